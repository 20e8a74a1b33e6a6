//! Make items on the pool, several at once, and take them one by one in order, with no
//! barrier between groups of items: the batch driver renders a unit's views with it and
//! appends them to the unit's tar in view order while later views render.
//!
//! `width` workers each claim the next index, make its item, then take every item ready
//! in order, unless another worker is taking them: at most one worker takes at a time,
//! and it looks again after letting go, so an item made while it held the taker is never
//! left behind. A worker makes only items fewer than `2 × width` ahead of the next to
//! take, so at most that many items are held (made or being made, not yet taken) at any
//! moment, whatever the makers' speeds; while it waits it takes what is ready itself.

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Mutex, MutexGuard, TryLockError};

/// The most items held at once by [`in_order`] with `width` workers.
pub(super) fn held_at_most(width: usize) -> usize {
    width.max(1).saturating_mul(2)
}

/// Make `make(k)` for `k` in `0..n` on the pool, `width` at once, and `take(k, item)` each
/// in order of `k` (see the module docs). The first error of `take` ends the run: no item
/// is made after it, none is taken after it, and it is returned.
pub(super) fn in_order<T, E, M, F>(n: usize, width: usize, make: M, take: F) -> Result<(), E>
where
    T: Send,
    E: Send,
    M: Fn(usize) -> T + Sync,
    F: FnMut(usize, T) -> Result<(), E> + Send,
{
    use rayon::prelude::*;
    let ahead = held_at_most(width);
    let order = Order {
        ready: Mutex::new(BTreeMap::new()),
        taker: Mutex::new(Taker {
            take,
            taken: 0,
            error: None,
        }),
        taken: AtomicUsize::new(0),
        failed: AtomicBool::new(false),
    };
    let next = AtomicUsize::new(0);
    let workers = width.clamp(1, rayon::current_num_threads().max(1)).min(n);
    (0..workers).into_par_iter().for_each(|_| {
        // A worker that panics would hold up the others' bound: they stop instead.
        let _stop_peers = FailOnUnwind(&order.failed);
        loop {
            let k = next.fetch_add(1, Ordering::Relaxed);
            if k >= n {
                break;
            }
            while k >= order.taken.load(Ordering::Acquire) + ahead
                && !order.failed.load(Ordering::Relaxed)
            {
                // The wait lasts one take at most: nap rather than spin, leaving the core
                // to the kernel's writeback and to hyperthread siblings.
                if !order.take_ready() {
                    std::thread::sleep(std::time::Duration::from_micros(50));
                }
            }
            if order.failed.load(Ordering::Relaxed) {
                break;
            }
            let item = make(k);
            lock(&order.ready).insert(k, item);
            order.take_ready();
        }
    });
    // Every worker has ended: whatever is still ready is taken here.
    order.take_ready();
    let taker = order.taker.into_inner().unwrap_or_else(|e| e.into_inner());
    match taker.error {
        Some(e) => Err(e),
        None => Ok(()),
    }
}

/// The items between their making and `take`.
struct Order<T, E, F> {
    /// Items made and not yet taken, by index.
    ready: Mutex<BTreeMap<usize, T>>,
    /// The one worker taking items at a time.
    taker: Mutex<Taker<E, F>>,
    /// Items taken so far, for the workers' bound.
    taken: AtomicUsize,
    /// `take` failed (or a worker panicked): no item is made after it.
    failed: AtomicBool,
}

/// What the worker taking items holds.
struct Taker<E, F> {
    take: F,
    /// Items taken: the index of the next to take.
    taken: usize,
    error: Option<E>,
}

impl<T, E, F: FnMut(usize, T) -> Result<(), E>> Order<T, E, F> {
    /// Take the items ready in order, unless another worker is taking them (it then sees
    /// the ones made meanwhile: it looks again after letting go). Whether any was taken.
    fn take_ready(&self) -> bool {
        let mut took = false;
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
            while taker.error.is_none() {
                let k = taker.taken;
                let Some(item) = lock(&self.ready).remove(&k) else {
                    break;
                };
                took = true;
                match (taker.take)(k, item) {
                    Ok(()) => taker.taken += 1,
                    Err(e) => {
                        taker.error = Some(e);
                        self.failed.store(true, Ordering::Relaxed);
                    }
                }
                self.taken.store(taker.taken, Ordering::Release);
            }
            let (k, failed) = (taker.taken, taker.error.is_some());
            drop(guard);
            // An item made while this worker held the taker found it busy: look again.
            if failed || !lock(&self.ready).contains_key(&k) {
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

    /// Items made at random speeds (0 to 300 µs) on a pool of `threads`: what `take` saw,
    /// and the most items ever held (claimed and not yet taken).
    fn run(
        n: usize,
        width: usize,
        threads: usize,
        fail_at: Option<usize>,
    ) -> (Vec<usize>, usize, Result<(), usize>) {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .expect("a pool");
        let started = AtomicUsize::new(0);
        let taken_count = AtomicUsize::new(0);
        let most = AtomicUsize::new(0);
        let mut seen = Vec::new();
        let result = pool.install(|| {
            in_order(
                n,
                width,
                |k| {
                    let s = started.fetch_add(1, Ordering::SeqCst) + 1;
                    let held = s - taken_count.load(Ordering::SeqCst);
                    most.fetch_max(held, Ordering::SeqCst);
                    let us = SplitMix64::for_item(7, k as u64).int_in(0, 300);
                    std::thread::sleep(Duration::from_micros(us as u64));
                    k * 10
                },
                |k, item| {
                    assert_eq!(item, k * 10, "an item reaches take with its own index");
                    if Some(k) == fail_at {
                        return Err(k);
                    }
                    seen.push(k);
                    taken_count.fetch_add(1, Ordering::SeqCst);
                    Ok(())
                },
            )
        });
        (seen, most.into_inner(), result)
    }

    #[test]
    fn items_are_taken_in_order_within_the_bound() {
        for (width, threads) in [(1, 1), (1, 4), (2, 2), (3, 4), (8, 4), (16, 8)] {
            let (seen, most, result) = run(300, width, threads, None);
            assert_eq!(result, Ok(()));
            assert_eq!(
                seen,
                (0..300).collect::<Vec<_>>(),
                "width {width}, {threads} threads"
            );
            assert!(
                most <= held_at_most(width),
                "width {width}, {threads} threads: {most} items held, more than {}",
                held_at_most(width)
            );
        }
        assert_eq!(run(0, 4, 2, None).0, Vec::<usize>::new());
    }

    #[test]
    fn a_failed_take_ends_the_run() {
        let (seen, _, result) = run(300, 4, 4, Some(40));
        assert_eq!(result, Err(40));
        assert_eq!(seen, (0..40).collect::<Vec<_>>());
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
