//! The thread pools every call runs on, and the waiting that lets Ctrl-C through (see the
//! crate's documentation).

use crate::errors::{memory_error, panic_error};
use pyo3::exceptions::{PyOSError, PyValueError};
use pyo3::prelude::*;
use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

/// The pools of this process, by thread count, and the process they belong to.
static POOLS: Mutex<Option<(u32, Pools)>> = Mutex::new(None);

/// One process's pools, by thread count.
type Pools = HashMap<usize, Arc<rayon::ThreadPool>>;

/// The pool of `threads` threads (`None`: every core) of this process, made on first use.
fn pool(threads: Option<usize>) -> PyResult<Arc<rayon::ThreadPool>> {
    let n = match threads {
        Some(n) if !(1..=MAX_THREADS).contains(&n) => {
            return Err(PyValueError::new_err(format!(
                "threads: must be in 1..={MAX_THREADS}, got {n}"
            )));
        }
        Some(n) => n,
        None => cores(),
    };
    let pid = std::process::id();
    let mut guard = POOLS.lock().unwrap_or_else(|e| e.into_inner());
    if guard.as_ref().is_some_and(|(p, _)| *p != pid) {
        // Inherited through fork: its threads live in the parent only. Dropping it would
        // wait on them; forget it instead.
        std::mem::forget(guard.take());
    }
    let (_, pools) = guard.get_or_insert_with(|| (pid, HashMap::new()));
    if let Some(p) = pools.get(&n) {
        return Ok(p.clone());
    }
    if pools.len() >= MAX_POOLS {
        // Forget the pools no call is using (their threads exit), so distinct counts do
        // not pile up threads for the life of the process.
        pools.retain(|_, p| Arc::strong_count(p) > 1);
    }
    let p = rayon::ThreadPoolBuilder::new()
        .num_threads(n)
        .build()
        .map_err(|e| PyOSError::new_err(format!("cannot start {n} threads: {e}")))?;
    // Each thread allocates once now: glibc gives a thread its own arena at its first
    // allocation, reserving 64 MiB of address space, which `ulimit -v` counts. Reserved
    // now, it is seen by the memory check a call makes before its buffers (on this pool,
    // [`check_memory`]); reserved later, it could take the room of the last plane of a
    // render that passed the check.
    p.broadcast(|_| drop(std::hint::black_box(Box::new(0u8))));
    let p = Arc::new(p);
    pools.insert(n, p.clone());
    Ok(p)
}

/// `cylaov::mem::check_memory` made on the pool of `threads` that will do the work, a
/// refusal as `MemoryError`: there the check counts the pool's threads as those still to
/// start (on the caller's thread it would ask rayon's global pool, starting it, and its
/// threads would take address space the package never uses), and the pool's threads have
/// made their reservations already (see [`pool`]).
pub(crate) fn check_memory(threads: Option<usize>, what: &str, bytes: u64) -> PyResult<()> {
    // What this call allocates is not in the views' allowance.
    *crate::arrays::AHEAD
        .lock()
        .unwrap_or_else(|e| e.into_inner()) = None;
    on_pool(threads, || cylaov::mem::check_memory(what, bytes))?.map_err(memory_error)
}

/// The bounds of `threads=`, those of `--threads`.
const MAX_THREADS: usize = 1024;

/// A `threads=` argument (`#[pyo3(from_py_with = threads_arg)]`): `None` (every core) or
/// an integer in 1..=[`MAX_THREADS`], the error naming it and the value
/// (`threads: must be in 1..=1024, got -1`).
pub(crate) fn threads_arg(obj: &Bound<'_, PyAny>) -> PyResult<Option<usize>> {
    if obj.is_none() {
        return Ok(None);
    }
    let n = crate::convert::integer(obj, "threads", 1, MAX_THREADS as i128)?;
    Ok(Some(n as usize))
}

/// Pools kept at most (beyond those in use): one per distinct thread count asked for.
const MAX_POOLS: usize = 4;

/// The cores this process may use, asked once: the standard library reads the cgroup's
/// files on every call, which costs more than a small view's trace gains from the pool.
fn cores() -> usize {
    static CORES: std::sync::OnceLock<usize> = std::sync::OnceLock::new();
    *CORES.get_or_init(|| std::thread::available_parallelism().map_or(1, |n| n.get()))
}

/// Run pure Rust `f` on this process's pool of `threads` threads, the GIL held (for quick
/// work: parsing, validation). Whatever uses rayon outside a pool's `install` takes rayon's
/// global pool, which after a fork is the parent's, without threads: so nothing here does.
pub(crate) fn on_pool<T: Send>(
    threads: Option<usize>,
    f: impl FnOnce() -> T + Send,
) -> PyResult<T> {
    pool(threads)?
        .install(|| std::panic::catch_unwind(std::panic::AssertUnwindSafe(f)))
        .map_err(panic_error)
}

/// Run `f` on the pool of `threads` threads with the GIL released.
pub(crate) fn run<T: Send>(
    py: Python<'_>,
    threads: Option<usize>,
    f: impl FnOnce() -> T + Send,
) -> PyResult<T> {
    let pool = pool(threads)?;
    py.detach(|| pool.install(|| std::panic::catch_unwind(std::panic::AssertUnwindSafe(f))))
        .map_err(panic_error)
}

/// How long the calling thread of a stoppable call waits for the work between two looks
/// for a signal: a Ctrl-C raises `KeyboardInterrupt` within this plus the time the work
/// takes to notice its stop flag (one band of a render, one view of a tar).
const SIGNAL_POLL: Duration = Duration::from_millis(20);

/// [`run`] for long work that takes a stop flag: the work runs on the pool while this
/// thread, the GIL released, waits for it and looks for signals every [`SIGNAL_POLL`]. An
/// exception from a signal handler (Ctrl-C's `KeyboardInterrupt`) sets the flag; the work
/// is waited for (it ends at its next look at the flag, cleaning up as it goes) and the
/// exception raised instead of its result.
pub(crate) fn run_stoppable<T: Send>(
    py: Python<'_>,
    threads: Option<usize>,
    f: impl FnOnce(&AtomicBool) -> T + Send,
) -> PyResult<T> {
    let pool = pool(threads)?;
    let stop = AtomicBool::new(false);
    // The work's result, and the condition variable its thread signals it on: no channel,
    // whose receiver would spin on the cores the work needs before it sleeps.
    let done: (Mutex<Option<std::thread::Result<T>>>, std::sync::Condvar) = Default::default();
    pool.in_place_scope(|s| {
        let (stop, done) = (&stop, &done);
        s.spawn(move |_| {
            let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| f(stop)));
            *done.0.lock().unwrap_or_else(|e| e.into_inner()) = Some(r);
            done.1.notify_one();
        });
        let mut raised: Option<PyErr> = None;
        loop {
            let got = py.detach(|| {
                let guard = done.0.lock().unwrap_or_else(|e| e.into_inner());
                let (mut guard, _) = done
                    .1
                    .wait_timeout_while(guard, SIGNAL_POLL, |r| r.is_none())
                    .unwrap_or_else(|e| e.into_inner());
                guard.take()
            });
            if let Some(r) = got {
                return match raised {
                    Some(e) => Err(e),
                    None => r.map_err(panic_error),
                };
            }
            if raised.is_none()
                && let Err(e) = py.check_signals()
            {
                stop.store(true, Ordering::Relaxed);
                raised = Some(e);
            }
        }
    })
}
