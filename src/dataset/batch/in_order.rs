//! Make items on the pool, several at once, and take them one by one in order, with no
//! barrier between groups of items: the batch driver renders a unit's views with it, lays
//! them out in the unit's tar (and hashes them) in view order while later views render,
//! and writes each where it was laid out.
//!
//! `width` workers each claim the next index, make its item, then take every item ready
//! in order, unless another worker is taking them: at most one worker takes at a time,
//! and it looks again after letting go, so an item made while it held the taker is never
//! left behind. What a take leaves (`after`: a view's bytes to write at their place) runs
//! on the worker that took it once it has let go, so the next items are taken meanwhile.
//! A worker claims only items fewer than `2 × width` ahead of the items done with (made,
//! taken and their `after` run), so at most that many are held at any moment, whatever
//! the makers' speeds; while it waits it takes what is ready itself.
//!
//! **No wait without end.** A pool thread that waits inside a job (a render waiting for
//! its bands, or a band waiting for its halves) runs other pool jobs meanwhile, a worker
//! among them. A worker that waited there at the bound could be waiting for the very item
//! suspended beneath it, forever. So a worker waits at the bound for [`PATIENCE`] at most,
//! then parks: it ends, counted, and the worker whose `after` moves the bound starts the
//! parked ones again. A worker holds no item while it waits at the bound, so parking
//! loses nothing; the bound's wait is short in the usual case (a take), so workers seldom
//! park.

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Mutex, MutexGuard, TryLockError};
use std::time::{Duration, Instant};

/// The most items held at once by [`in_order`] with `width` workers.
pub(super) fn held_at_most(width: usize) -> usize {
    width.max(1).saturating_mul(2)
}

/// How long a worker waits at the bound before it parks (see the module docs): about a
/// small view's render, so an ordinary wait (a take, a view finishing) ends first.
const PATIENCE: Duration = Duration::from_millis(2);

/// How long a worker naps between looks at the bound: short against [`PATIENCE`] and a
/// take, long enough to leave the core to the others and to the kernel's writeback.
const NAP: Duration = Duration::from_micros(50);

/// Make `make(k)` for `k` in `0..n` on the pool, `width` at once, `take(k, item)` each in
/// order of `k`, and run `after` on what each take returns, in any order (see the module
/// docs). The first error of `take` or `after` ends the run: no item is claimed or taken
/// once a worker has seen it (a take already under way has its `after` run), and it is
/// returned (`take`'s first).
pub(super) fn in_order<T, A, E, M, F, W>(
    n: usize,
    width: usize,
    make: M,
    take: F,
    after: W,
) -> Result<(), E>
where
    T: Send,
    A: Send,
    E: Send,
    M: Fn(usize) -> T + Sync,
    F: FnMut(usize, T) -> Result<A, E> + Send,
    W: Fn(A) -> Result<(), E> + Sync,
{
    let run = Run {
        n,
        ahead: held_at_most(width),
        make: &make,
        after: &after,
        next: AtomicUsize::new(0),
        parked: AtomicUsize::new(0),
        order: Order {
            ready: Mutex::new(BTreeMap::new()),
            taker: Mutex::new(Taker {
                take,
                taken: 0,
                error: None,
            }),
            done: AtomicUsize::new(0),
            failed: AtomicBool::new(false),
            late: Mutex::new(None),
        },
        _taken: std::marker::PhantomData,
    };
    let workers = width.clamp(1, rayon::current_num_threads().max(1)).min(n);
    rayon::scope(|s| {
        for _ in 0..workers {
            s.spawn(|s| run.work(Some(s)));
        }
    });
    // Every worker has ended, with no item left to claim, or the run failed (a panic is
    // raised again by the scope). A guard that finds nothing to do: were any item left,
    // it would be made and taken here in turn.
    run.work(None);
    let Run { order, .. } = run;
    let taker = order.taker.into_inner().unwrap_or_else(|e| e.into_inner());
    let late = order.late.into_inner().unwrap_or_else(|e| e.into_inner());
    match taker.error.or(late) {
        Some(e) => Err(e),
        None => Ok(()),
    }
}

/// One call of [`in_order`].
struct Run<'r, T, A, E, M, F, W> {
    n: usize,
    ahead: usize,
    make: &'r M,
    after: &'r W,
    /// The next index to claim.
    next: AtomicUsize,
    /// Workers parked at the bound, to start again when it moves.
    parked: AtomicUsize,
    order: Order<T, E, F>,
    _taken: std::marker::PhantomData<fn() -> A>,
}

impl<'r, T, A, E, M, F, W> Run<'r, T, A, E, M, F, W>
where
    T: Send,
    A: Send,
    E: Send,
    M: Fn(usize) -> T + Sync,
    F: FnMut(usize, T) -> Result<A, E> + Send,
    W: Fn(A) -> Result<(), E> + Sync,
{
    /// A worker: claim, make and take items until none is left or the run fails; at the
    /// bound, wait for [`PATIENCE`] at most, then park. Without a scope (`s` is `None`:
    /// the caller's last pass) it goes on past the bound, taking each item as it makes it.
    fn work<'s>(&'s self, s: Option<&rayon::Scope<'s>>) {
        // A worker that panics fails the run, so no worker waits for its item.
        let _stop_peers = FailOnUnwind(&self.order.failed);
        let mut waiting_since: Option<Instant> = None;
        loop {
            if self.order.failed.load(Ordering::Relaxed) {
                return;
            }
            let k = self.next.load(Ordering::Acquire);
            if k >= self.n {
                self.take_and_finish(s);
                return;
            }
            if let Some(s) = s
                && k >= self.bound()
            {
                if self.take_and_finish(Some(s)) {
                    waiting_since = None;
                    continue;
                }
                let since = *waiting_since.get_or_insert_with(Instant::now);
                if since.elapsed() < PATIENCE {
                    std::thread::sleep(NAP);
                    continue;
                }
                self.parked.fetch_add(1, Ordering::AcqRel);
                // The bound may have moved between the look and the count: whoever moved
                // it may have found no one parked, so look again.
                if k < self.bound() {
                    self.unpark(s);
                }
                return;
            }
            waiting_since = None;
            if self
                .next
                .compare_exchange(k, k + 1, Ordering::AcqRel, Ordering::Acquire)
                .is_err()
            {
                continue;
            }
            let item = (self.make)(k);
            lock(&self.order.ready).insert(k, item);
            self.take_and_finish(s);
        }
    }

    /// The first index a worker may not claim yet: `ahead` past the items done with.
    fn bound(&self) -> usize {
        self.order
            .done
            .load(Ordering::Acquire)
            .saturating_add(self.ahead)
    }

    /// Start the parked workers again (each looks at the bound anew).
    fn unpark<'s>(&'s self, s: &rayon::Scope<'s>) {
        for _ in 0..self.parked.swap(0, Ordering::AcqRel) {
            s.spawn(|s| self.work(Some(s)));
        }
    }

    /// Take what is ready, run `after` on it with the taker let go, and start parked
    /// workers if that moved the bound. Whether any item was taken.
    fn take_and_finish<'s>(&'s self, s: Option<&rayon::Scope<'s>>) -> bool {
        let taken = self.order.take_ready();
        let any = !taken.is_empty();
        for a in taken {
            if let Err(e) = (self.after)(a) {
                self.order.failed.store(true, Ordering::Relaxed);
                lock(&self.order.late).get_or_insert(e);
            }
            self.order.done.fetch_add(1, Ordering::AcqRel);
            // The bound moved: start the parked now, not after the rest of the batch.
            if let Some(s) = s {
                self.unpark(s);
            }
        }
        any
    }
}

/// The items between their making and `take`.
struct Order<T, E, F> {
    /// Items made and not yet taken, by index.
    ready: Mutex<BTreeMap<usize, T>>,
    /// The one worker taking items at a time.
    taker: Mutex<Taker<E, F>>,
    /// Items done with (taken and their `after` run), for the workers' bound.
    done: AtomicUsize,
    /// `take` or `after` failed (or a worker panicked): no item is made after it.
    failed: AtomicBool,
    /// The first error of `after`.
    late: Mutex<Option<E>>,
}

/// What the worker taking items holds.
struct Taker<E, F> {
    take: F,
    /// Items taken: the index of the next to take.
    taken: usize,
    error: Option<E>,
}

impl<T, E, F> Order<T, E, F> {
    /// Take the items ready in order, unless another worker is taking them (it then sees
    /// the ones made meanwhile: it looks again after letting go), until the run fails;
    /// what the takes returned.
    fn take_ready<A>(&self) -> Vec<A>
    where
        F: FnMut(usize, T) -> Result<A, E>,
    {
        let mut took = Vec::new();
        loop {
            let mut guard = match self.taker.try_lock() {
                Ok(guard) => guard,
                Err(TryLockError::WouldBlock) => return took,
                Err(TryLockError::Poisoned(_)) => {
                    self.failed.store(true, Ordering::Relaxed);
                    return took;
                }
            };
            let taker = &mut *guard;
            while taker.error.is_none() && !self.failed.load(Ordering::Relaxed) {
                let k = taker.taken;
                let Some(item) = lock(&self.ready).remove(&k) else {
                    break;
                };
                match (taker.take)(k, item) {
                    Ok(a) => {
                        took.push(a);
                        taker.taken += 1;
                    }
                    Err(e) => {
                        taker.error = Some(e);
                        self.failed.store(true, Ordering::Relaxed);
                    }
                }
            }
            let k = taker.taken;
            drop(guard);
            // An item made while this worker held the taker found it busy: look again.
            if self.failed.load(Ordering::Relaxed) || !lock(&self.ready).contains_key(&k) {
                return took;
            }
        }
    }
}

/// Sets its flag when dropped by a panic.
struct FailOnUnwind<'a>(&'a AtomicBool);

impl Drop for FailOnUnwind<'_> {
    fn drop(&mut self) {
        if std::thread::panicking() {
            self.0.store(true, Ordering::Relaxed);
        }
    }
}

/// A mutex's content, through a poisoned lock too (a panicking worker already fails the
/// run; its peers need not panic again).
fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::SplitMix64;
    use std::time::Duration;

    /// Where a run fails, if it does.
    #[derive(Clone, Copy, PartialEq)]
    enum Fail {
        Never,
        Take(usize),
        After(usize),
    }

    /// A sleep of 0 to 300 µs, the same for the same `(seed, k)`.
    fn nap(seed: u64, k: usize) {
        let us = SplitMix64::for_item(seed, k as u64).int_in(0, 300);
        std::thread::sleep(Duration::from_micros(us as u64));
    }

    /// Items made and finished at random speeds on a pool of `threads`: the order `take`
    /// saw them in, the items whose `after` ran, the most items ever held (claimed and not
    /// done with), and the result.
    fn run(
        n: usize,
        width: usize,
        threads: usize,
        fail: Fail,
    ) -> (Vec<usize>, Vec<usize>, usize, Result<(), usize>) {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .expect("a pool");
        let started = AtomicUsize::new(0);
        let finished = AtomicUsize::new(0);
        let most = AtomicUsize::new(0);
        let afters = Mutex::new(Vec::new());
        let mut seen = Vec::new();
        let result = pool.install(|| {
            in_order(
                n,
                width,
                |k| {
                    let s = started.fetch_add(1, Ordering::SeqCst) + 1;
                    most.fetch_max(s - finished.load(Ordering::SeqCst), Ordering::SeqCst);
                    nap(7, k);
                    k * 10
                },
                |k, item| {
                    assert_eq!(item, k * 10, "an item reaches take with its own index");
                    if fail == Fail::Take(k) {
                        return Err(k);
                    }
                    seen.push(k);
                    Ok(k)
                },
                |k| {
                    nap(8, k);
                    lock(&afters).push(k);
                    finished.fetch_add(1, Ordering::SeqCst);
                    if fail == Fail::After(k) {
                        return Err(k);
                    }
                    Ok(())
                },
            )
        });
        let mut afters = afters.into_inner().expect("no panic");
        afters.sort_unstable();
        (seen, afters, most.into_inner(), result)
    }

    #[test]
    fn items_are_taken_in_order_within_the_bound() {
        for (width, threads) in [(1, 1), (1, 4), (2, 2), (3, 4), (8, 4), (16, 8)] {
            let (seen, afters, most, result) = run(300, width, threads, Fail::Never);
            assert_eq!(result, Ok(()));
            let all: Vec<usize> = (0..300).collect();
            assert_eq!(seen, all, "width {width}, {threads} threads");
            assert_eq!(afters, all, "width {width}, {threads} threads");
            assert!(
                most <= held_at_most(width),
                "width {width}, {threads} threads: {most} items held, more than {}",
                held_at_most(width)
            );
        }
        let (seen, afters, _, result) = run(0, 4, 2, Fail::Never);
        assert_eq!((seen.len(), afters.len(), result), (0, 0, Ok(())));
    }

    #[test]
    fn a_failed_take_ends_the_run() {
        let (seen, afters, _, result) = run(300, 4, 4, Fail::Take(40));
        assert_eq!(result, Err(40));
        assert_eq!(seen, (0..40).collect::<Vec<_>>());
        assert_eq!(afters, seen, "what was taken is finished");
    }

    /// A failed `after` ends the run too: the items taken are those up to it and a few
    /// more (takes that began before the failure was seen), in order, each finished, and
    /// the rest never start.
    #[test]
    fn a_failed_after_ends_the_run() {
        let (seen, afters, _, result) = run(300, 4, 4, Fail::After(40));
        assert_eq!(result, Err(40));
        assert_eq!(seen, (0..seen.len()).collect::<Vec<_>>());
        assert!((41..100).contains(&seen.len()), "{} taken", seen.len());
        assert_eq!(afters, seen, "what was taken is finished");
    }

    /// A `make` that itself runs on the pool (as a render does) may have a worker run on
    /// one of its threads while a part of it waits for its own jobs, and that worker must
    /// not wait without end for the suspended item beneath it. Two runs at once (as the
    /// driver's tars are), each as wide as the pool, so workers queue in the pool; many
    /// small items, each split in parts that yield to the pool's queued jobs while their
    /// halves run elsewhere. (This makes such schedules likely, not certain:
    /// `a_worker_above_a_suspended_item_parks` forces one.) A run that never ends
    /// fails after 60 s.
    #[test]
    fn makers_that_use_the_pool_never_wait_on_each_other() {
        use rayon::prelude::*;
        fn one(width: usize) -> Vec<usize> {
            let mut seen = Vec::new();
            in_order(
                300,
                width,
                |k| {
                    (0..4u64)
                        .into_par_iter()
                        .map(|j| {
                            let f = |x: u64| (0..200u64).fold(x, |a, b| a.rotate_left(5) ^ b);
                            let (a, b) = rayon::join(
                                || {
                                    nap(k as u64, j as usize);
                                    f(k as u64 ^ j)
                                },
                                || {
                                    let _ = rayon::yield_now();
                                    nap(k as u64 + 1, j as usize);
                                    f(j)
                                },
                            );
                            a ^ b
                        })
                        .sum::<u64>()
                },
                |k, _| {
                    seen.push(k);
                    Ok::<(), ()>(())
                },
                |()| Ok(()),
            )
            .expect("no take fails");
            seen
        }
        for threads in [2, 4, 8] {
            let (send, done) = std::sync::mpsc::channel();
            std::thread::spawn(move || {
                let pool = rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .expect("a pool");
                let _ = send.send(pool.install(|| rayon::join(|| one(threads), || one(threads))));
            });
            let (a, b) = done
                .recv_timeout(Duration::from_secs(60))
                .unwrap_or_else(|_| panic!("{threads} threads: the runs never ended"));
            let all: Vec<usize> = (0..300).collect();
            assert_eq!((a, b), (all.clone(), all), "{threads} threads");
        }
    }

    /// Forces the schedule of the module docs: while item 0 is being made, its thread
    /// runs the run's other worker (`yield_local` runs the job waiting in the thread's
    /// own queue, as a render's wait for its bands may), which makes items 1 to 3 and
    /// then meets the bound, item 0 beneath it. It must park rather than wait on (a wait
    /// would never end); the run then finishes in order.
    #[test]
    fn a_worker_above_a_suspended_item_parks() {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(2)
            .build()
            .expect("a pool");
        let (send, done) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            let busy = AtomicBool::new(true);
            let nested = AtomicUsize::new(0);
            thread_local! {
                static IN_ITEM_0: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
            }
            let mut seen = Vec::new();
            pool.install(|| {
                rayon::join(
                    || {
                        let r = in_order(
                            20,
                            2,
                            |k| {
                                if k == 0 {
                                    // The other worker waits in this thread's queue (the
                                    // pool's other thread spins below).
                                    IN_ITEM_0.with(|c| c.set(true));
                                    let _ = rayon::yield_local();
                                    IN_ITEM_0.with(|c| c.set(false));
                                } else if IN_ITEM_0.with(|c| c.get()) {
                                    nested.fetch_add(1, Ordering::SeqCst);
                                }
                                k
                            },
                            |k, item| {
                                seen.push((k, item));
                                Ok::<(), ()>(())
                            },
                            |()| Ok(()),
                        );
                        busy.store(false, Ordering::SeqCst);
                        r
                    },
                    || {
                        while busy.load(Ordering::SeqCst) {
                            std::hint::spin_loop();
                        }
                    },
                )
            })
            .0
            .expect("no take fails");
            let _ = send.send((seen, nested.into_inner()));
        });
        let (seen, nested) = done
            .recv_timeout(Duration::from_secs(20))
            .expect("the run ends (a worker waited above the item it needed)");
        assert_eq!(nested, 3, "items 1 to 3 made above item 0, then the bound");
        assert_eq!(seen, (0..20).map(|k| (k, k)).collect::<Vec<_>>());
    }

    /// The bound holds the makers back: a stalled first item lets at most the bound's
    /// items start, however fast the others are.
    #[test]
    fn a_slow_item_holds_back_the_makers() {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(4)
            .build()
            .expect("a pool");
        let started_while_slow = AtomicUsize::new(0);
        let slow_done = AtomicBool::new(false);
        pool.install(|| {
            in_order(
                100,
                2,
                |k| {
                    if k == 0 {
                        std::thread::sleep(Duration::from_millis(50));
                        slow_done.store(true, Ordering::SeqCst);
                    } else if !slow_done.load(Ordering::SeqCst) {
                        started_while_slow.fetch_add(1, Ordering::SeqCst);
                    }
                },
                |_, ()| Ok::<(), ()>(()),
                |()| Ok(()),
            )
        })
        .expect("no take fails");
        // Items 1 to 3 may start while item 0 sleeps; item 4 is two widths ahead.
        let n = started_while_slow.into_inner();
        assert!(
            (1..held_at_most(2)).contains(&n),
            "{n} items started behind the slow one"
        );
    }
}
