//! Memory: how much a command may use, what its large buffers cost, and what happens when
//! the system refuses one. Used by every stage, so it belongs to none.
//!
//! - **Before allocating**: [`check_memory`] refuses a command whose estimate exceeds what
//!   the machine, `ulimit -v` or the cgroup leave ([`memory_available`]), with one line
//!   naming what needed it.
//! - **Our own large buffers** are reserved with [`try_reserve`], [`try_zeroed`] and
//!   [`try_copy`]: a refusal is an error naming the buffer, like any
//!   other.
//! - **Everything else** (buffers inside crates such as `exr` and `image`) goes through the
//!   process's allocator, [`Guarded`]: where Rust would print "memory allocation of N bytes
//!   failed" and abort (status 134), it prints one `error:` line, runs the clean-up of
//!   [`set_cleanup`] (the registry of staged files) and exits with the command's status
//!   for too little memory ([`set_out_of_memory_status`]: 1, or 2 in `compare` and
//!   `verify`, where 1 means a broken tolerance).
//! - The 2 MiB-page hint and the allocator policy for the large buffers of a render.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::io;
use std::sync::atomic::{AtomicBool, AtomicI32, AtomicUsize, Ordering};

/// Ask Linux to back the untouched memory of `v` (its whole capacity) with 2 MiB pages.
/// A 1080p plane is 8 MB: faulting it in 4 KiB pages took about a third of a render's
/// time. Only the 2 MiB-aligned interior can be marked; the hint changes no byte, and a
/// kernel without transparent huge pages ignores it.
pub(crate) fn huge_pages<X>(v: &Vec<X>) {
    #[cfg(target_os = "linux")]
    {
        const HUGE: usize = 2 << 20;
        let begin = v.as_ptr() as usize;
        let end = begin + v.capacity() * size_of::<X>();
        let (lo, hi) = (begin.next_multiple_of(HUGE), end / HUGE * HUGE);
        if hi > lo {
            // SAFETY: [lo, hi) lies inside `v`'s allocation; MADV_HUGEPAGE only changes
            // how the kernel backs those pages, never their contents.
            unsafe { libc::madvise(lo as *mut libc::c_void, hi - lo, libc::MADV_HUGEPAGE) };
        }
    }
    #[cfg(not(target_os = "linux"))]
    let _ = v;
}

/// How many elements ahead a gather [`prefetch`]es: enough to cover a miss (a few hundred
/// ns) with the work of the elements between.
pub(crate) const PREFETCH_AHEAD: usize = 16;

/// Start loading the cache lines of `x` now: for gathers in an order that memory's does
/// not follow, whose misses would otherwise each be waited for in turn (preparing 100 000
/// cylinders in the trace's order stalled on nearly every one). A hint: no value changes.
#[inline(always)]
pub(crate) fn prefetch<X>(x: &X) {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
        let p = (x as *const X).cast::<i8>();
        // Every line `x` touches: one each 64 bytes from its start, and its last byte's.
        for at in (0..size_of::<X>())
            .step_by(64)
            .chain([size_of::<X>().saturating_sub(1)])
        {
            // SAFETY: SSE is part of x86_64; a prefetch reads nothing into the program and
            // never faults, whatever the address.
            unsafe { _mm_prefetch::<_MM_HINT_T0>(p.wrapping_add(at)) };
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = x;
}

/// Keep the memory a process frees for its own later allocations, instead of returning
/// each large block to the kernel (glibc maps every block over 128 KiB on its own and
/// unmaps it when freed). A render frees the scene file's bytes before it allocates the
/// prepared cylinders, and the BVH build's scratch before the trace: reused, those pages
/// are already faulted in, where fresh ones cost a kernel fault and zeroing each (on the
/// virtual machines measured here about 1 ms per MiB: 10 of the 58 ms of a 16×16 render
/// of 100 000 cylinders). A policy for the whole process, so the command line sets it
/// once at start; other allocators than glibc's are left as they are.
///
/// Under `ulimit -v` glibc also keeps to one arena: each thread's own arena reserves
/// 64 MiB of address space it mostly never uses, and the limit counts it (a ZIP-compressed
/// 2048² render with every AOV ran under `ulimit -v 540000` with one arena and ran out of
/// address space under 580000 with glibc's default). The render's hot loops do not
/// allocate, so they do not contend for the one arena.
pub fn keep_freed_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        // glibc's largest mmap threshold on 64-bit targets (larger values are refused).
        const MMAP_MAX: libc::c_int = 32 << 20;
        let limited = address_space_limit().is_some();
        // SAFETY: `mallopt` only changes glibc's allocation policy for later allocations;
        // it is thread-safe, and a refused value leaves the policy as it was.
        unsafe {
            libc::mallopt(libc::M_MMAP_THRESHOLD, MMAP_MAX);
            libc::mallopt(libc::M_TRIM_THRESHOLD, libc::c_int::MAX);
            if limited {
                libc::mallopt(libc::M_ARENA_MAX, 1);
            }
        }
    }
}

/// Peak resident memory of this process in MiB (Linux `VmHWM`), if the OS tells.
pub fn peak_rss_mib() -> Option<f64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kib: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib / 1024.0)
}

/// Bytes this process can still allocate, as far as the OS tells: the smallest of the
/// memory available to the machine (`MemAvailable` plus free swap, `/proc/meminfo`), the
/// address space left under `RLIMIT_AS` (`ulimit -v`, minus the current `VmSize`) and the
/// cgroup's `memory.max` minus `memory.current` (containers, Slurm, Kubernetes), each plus
/// the memory this process freed and kept for reuse ([`keep_freed_memory`]: the next
/// view of a batch reuses the last one's). `None` when none of them is known.
pub fn memory_available() -> Option<u64> {
    left_by_os().map(|b| b.saturating_add(kept_free()))
}

/// [`memory_available`] without the memory this process keeps for reuse.
fn left_by_os() -> Option<u64> {
    let mut best: Option<u64> = None;
    let mut take = |x: Option<u64>| {
        if let Some(x) = x {
            best = Some(best.map_or(x, |b| b.min(x)));
        }
    };
    take(meminfo_available());
    take(address_space_left());
    take(cgroup_left());
    best
}

/// Bytes the allocator holds free for reuse: counted as used by the kernel, the limit and
/// the cgroup, yet ours to allocate again (glibc's `mallinfo2`; 0 elsewhere).
fn kept_free() -> u64 {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        // SAFETY: `mallinfo2` only reads the allocator's statistics.
        let info = unsafe { libc::mallinfo2() };
        info.fordblks as u64
    }
    #[cfg(not(all(target_os = "linux", target_env = "gnu")))]
    0
}

/// A `/proc` style `Key:   123 kB` value in bytes.
fn kib_field(text: &str, key: &str) -> Option<u64> {
    let line = text.lines().find(|l| l.starts_with(key))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib * 1024)
}

fn meminfo_available() -> Option<u64> {
    let m = std::fs::read_to_string("/proc/meminfo").ok()?;
    Some(kib_field(&m, "MemAvailable:")? + kib_field(&m, "SwapFree:").unwrap_or(0))
}

/// `RLIMIT_AS` (`ulimit -v`) in bytes, if one is set.
#[cfg(target_os = "linux")]
fn address_space_limit() -> Option<u64> {
    let mut lim = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: getrlimit only writes the struct it is given.
    if unsafe { libc::getrlimit(libc::RLIMIT_AS, &mut lim) } != 0
        || lim.rlim_cur == libc::RLIM_INFINITY
    {
        return None;
    }
    #[allow(clippy::unnecessary_cast)] // rlim_t is narrower than u64 on some targets
    Some(lim.rlim_cur as u64)
}

#[cfg(not(target_os = "linux"))]
fn address_space_limit() -> Option<u64> {
    None
}

/// The address space left under `RLIMIT_AS`: the limit minus the current `VmSize`, minus
/// what the threads still to start will reserve ([`thread_reserve`]).
fn address_space_left() -> Option<u64> {
    let limit = address_space_limit()?;
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let used = kib_field(&status, "VmSize:").unwrap_or(0);
    Some(limit.saturating_sub(used).saturating_sub(thread_reserve()))
}

/// Address space the threads of a command reserve beyond its heap, which `ulimit -v`
/// counts: a stack (Rust's default 2 MiB, plus a guard page) for each thread of the render
/// pool and of the `exr` encoder's own pool, one of each per core, whether or not they have
/// started yet; and 16 MiB for the loader's and allocator's own mappings. (Thread arenas
/// are off under a limit, see [`keep_freed_memory`].)
fn thread_reserve() -> u64 {
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get()) as u64;
    let threads = 2 * cores.max(rayon::current_num_threads() as u64);
    threads * ((2 << 20) + 4096) + (16 << 20)
}

fn cgroup_left() -> Option<u64> {
    let max = std::fs::read_to_string("/sys/fs/cgroup/memory.max").ok()?;
    let max: u64 = max.trim().parse().ok()?; // "max" means no limit
    let cur: u64 = std::fs::read_to_string("/sys/fs/cgroup/memory.current")
        .ok()?
        .trim()
        .parse()
        .ok()?;
    Some(max.saturating_sub(cur))
}

/// Fail with a clear message, before allocating, when `bytes` (what `what` needs) exceeds
/// [`memory_available`]. Unknown availability passes: the allocator then has the last word.
pub fn check_memory(what: &str, bytes: u64) -> io::Result<()> {
    // `memory_available` is what the OS leaves plus what the allocator keeps, never less
    // than the first: what fits in it fits, and the allocator's statistics (a walk of its
    // free lists, read for every view of a batch) are read only when it does not.
    let left = left_by_os();
    if left.is_some_and(|left| bytes <= left) {
        return Ok(());
    }
    match left.map(|b| b.saturating_add(kept_free())) {
        Some(avail) if bytes > avail => Err(io::Error::new(
            io::ErrorKind::OutOfMemory,
            format!(
                "{what} needs about {} of memory, only {} is available (free memory, ulimit -v and the cgroup limit)",
                mib(bytes),
                mib(avail)
            ),
        )),
        _ => Ok(()),
    }
}

fn mib(bytes: u64) -> String {
    format!("{:.0} MiB", bytes as f64 / (1u64 << 20) as f64)
}

/// How many jobs of `bytes_each` may run at once within half of [`memory_available`], at
/// least 1 and at most `wanted` (the thread count): the batch renders this many views at a
/// time, so its peak memory does not grow with the core count. The other half is headroom
/// for encoders, page cache and the rest of the machine.
pub fn jobs_in_memory(bytes_each: u64, wanted: usize) -> usize {
    let wanted = wanted.max(1);
    match memory_available() {
        Some(avail) if bytes_each > 0 => ((avail / 2 / bytes_each) as usize).clamp(1, wanted),
        _ => wanted,
    }
}

// ---- failed allocations --------------------------------------------------------------------

/// The process's global allocator (installed by the command line): the system allocator,
/// with a failed allocation turned into the one-line error and the exit status of
/// [`set_out_of_memory_status`] instead of Rust's abort (stable Rust has no hook for that,
/// `std::alloc::set_alloc_error_hook` is unstable, so the allocator itself reports before
/// returning). Allocations made through [`try_reserve`], [`try_zeroed`] and [`try_copy`]
/// are exempt: their refusal comes back as an error.
///
/// [`Guarded::COUNTING`] also counts the live heap bytes and their peak ([`heap_peak`]),
/// which the tests use to hold the estimates to what the code really allocates.
pub struct Guarded {
    count: bool,
}

impl Guarded {
    /// The allocator of the command line: no counting.
    pub const PLAIN: Guarded = Guarded { count: false };
    /// The allocator that also keeps [`heap_live`] and [`heap_peak`].
    pub const COUNTING: Guarded = Guarded { count: true };

    fn grew(&self, by: usize) {
        if self.count {
            let live = LIVE.fetch_add(by, Ordering::Relaxed) + by;
            PEAK.fetch_max(live, Ordering::Relaxed);
        }
    }

    fn shrank(&self, by: usize) {
        if self.count {
            LIVE.fetch_sub(by, Ordering::Relaxed);
        }
    }
}

static LIVE: AtomicUsize = AtomicUsize::new(0);
static PEAK: AtomicUsize = AtomicUsize::new(0);
/// Allocations larger than this fail, as a refusing system would (tests only, see
/// [`init_from_env`]).
static FAIL_OVER: AtomicUsize = AtomicUsize::new(usize::MAX);
/// The clean-up to run before exiting on a failed allocation (a `fn()` as usize; 0 = none).
static CLEANUP: AtomicUsize = AtomicUsize::new(0);
/// Set by the first thread that reports a failed allocation.
static FAILING: AtomicBool = AtomicBool::new(false);
/// The exit status of a failed allocation (see [`set_out_of_memory_status`]).
static OOM_STATUS: AtomicI32 = AtomicI32::new(1);

thread_local! {
    /// Whether this thread's allocations may fail back to the caller (inside [`fallibly`]).
    static FALLIBLE: Cell<bool> = const { Cell::new(false) };
    /// Set on the thread that is reporting a failed allocation: a second failure on it
    /// (inside the clean-up) ends the process at once instead of waiting for itself.
    static EXITING: Cell<bool> = const { Cell::new(false) };
}

// SAFETY: every method forwards to `System` with the caller's layout and pointer; the
// bookkeeping touches only atomics and a const thread-local without a destructor.
unsafe impl GlobalAlloc for Guarded {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let p = if layout.size() > FAIL_OVER.load(Ordering::Relaxed) {
            std::ptr::null_mut()
        } else {
            // SAFETY: the caller's layout, as `GlobalAlloc::alloc` requires.
            unsafe { System.alloc(layout) }
        };
        self.checked(p, layout.size(), 0)
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        let p = if layout.size() > FAIL_OVER.load(Ordering::Relaxed) {
            std::ptr::null_mut()
        } else {
            // SAFETY: as in `alloc`.
            unsafe { System.alloc_zeroed(layout) }
        };
        self.checked(p, layout.size(), 0)
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: `ptr` came from this allocator (that is, `System`) with `layout`.
        unsafe { System.dealloc(ptr, layout) };
        self.shrank(layout.size());
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        let p = if new_size > FAIL_OVER.load(Ordering::Relaxed) {
            std::ptr::null_mut()
        } else {
            // SAFETY: as in `dealloc`; a null return leaves the old block in place.
            unsafe { System.realloc(ptr, layout, new_size) }
        };
        self.checked(p, new_size, layout.size())
    }
}

impl Guarded {
    /// `p` for an allocation of `size` bytes replacing `old`: counted when it succeeded;
    /// when it failed, null back to a [`fallibly`] caller, else the report and exit.
    fn checked(&self, p: *mut u8, size: usize, old: usize) -> *mut u8 {
        if p.is_null() {
            if FALLIBLE.try_with(Cell::get).unwrap_or(false) {
                return p;
            }
            out_of_memory(size);
        }
        if size >= old {
            self.grew(size - old);
        } else {
            self.shrank(old - size);
        }
        p
    }
}

/// Live heap bytes (with [`Guarded::COUNTING`] installed; else 0).
pub fn heap_live() -> usize {
    LIVE.load(Ordering::Relaxed)
}

/// The largest [`heap_live`] since the last [`reset_heap_peak`].
pub fn heap_peak() -> usize {
    PEAK.load(Ordering::Relaxed)
}

/// Start a new [`heap_peak`] from the current live bytes.
pub fn reset_heap_peak() {
    PEAK.store(LIVE.load(Ordering::Relaxed), Ordering::Relaxed);
}

/// Register the clean-up a failed allocation runs before the process reports it and exits
/// (the registry of staged temporary files sets it): it returns how many unfinished files
/// and folders it removed, must not need much memory, and runs at most once.
pub fn set_cleanup(f: fn() -> usize) {
    CLEANUP.store(f as usize, Ordering::SeqCst);
}

/// Set the exit status of a failed allocation that ends the process (1 unless set): a
/// command whose status 1 means something else (`compare`, `verify`: a broken tolerance)
/// sets the status of a check that could not be made, 2. Set once at start, before the
/// command allocates.
pub fn set_out_of_memory_status(status: i32) {
    OOM_STATUS.store(status, Ordering::SeqCst);
}

/// The exit status a failed allocation ends the process with.
fn out_of_memory_status() -> i32 {
    OOM_STATUS.load(Ordering::SeqCst)
}

/// Read the test switch `CYLAOV_FAIL_ALLOC_OVER=BYTES`: every later allocation larger
/// than BYTES fails as a refusing system's would, to test the reporting path without
/// exhausting the machine. Any other value is ignored. Called once at start.
pub fn init_from_env() {
    if let Some(n) = std::env::var("CYLAOV_FAIL_ALLOC_OVER")
        .ok()
        .and_then(|v| v.parse::<usize>().ok())
    {
        FAIL_OVER.store(n, Ordering::Relaxed);
    }
}

/// Run `f` with this thread's failed allocations returned to their caller (what
/// `try_reserve` needs to see its `Err`) instead of reported by [`Guarded`].
fn fallibly<R>(f: impl FnOnce() -> R) -> R {
    let before = FALLIBLE.with(|c| c.replace(true));
    let r = f();
    FALLIBLE.with(|c| c.set(before));
    r
}

/// The one-line report of a failed allocation of `size` bytes, then the clean-up and
/// `_exit` with the command's status ([`set_out_of_memory_status`]). Allocates nothing:
/// the line is built on the stack and written with `write(2)`. A second thread failing
/// meanwhile waits for the first to exit.
fn out_of_memory(size: usize) -> ! {
    exit_after(|removed| {
        let mut line = Line::default();
        line.push(b"error: out of memory: an allocation of ");
        line.push_size(size);
        line.push(b" was refused (free memory, ulimit -v or the cgroup limit)");
        if removed > 0 {
            line.push(b"; the unfinished files were removed");
        }
        line.push(b"\n");
        // SAFETY: writes `line.len` initialised bytes of a stack buffer to stderr.
        unsafe { libc::write(2, line.buf.as_ptr().cast(), line.len) };
    })
}

/// Run the clean-up of [`set_cleanup`], print the report (`report`, given how many files
/// it removed) and `_exit` with [`set_out_of_memory_status`]'s status: no unwinding, no destructors. A second thread failing
/// meanwhile waits for the first to end the process; a failure inside the clean-up exits
/// at once.
fn exit_after(report: impl FnOnce(usize)) -> ! {
    if EXITING.try_with(Cell::get).unwrap_or(true) {
        // SAFETY: ends the process at once, with no unwinding and no allocator.
        unsafe { libc::_exit(out_of_memory_status()) }
    }
    if FAILING.swap(true, Ordering::SeqCst) {
        loop {
            // SAFETY: `pause` only waits for a signal; the first thread ends the process.
            unsafe { libc::pause() };
        }
    }
    let _ = EXITING.try_with(|c| c.set(true));
    let f = CLEANUP.load(Ordering::SeqCst);
    let removed = if f != 0 {
        // SAFETY: only `set_cleanup` stores here, and it stores a `fn() -> usize`.
        let f: fn() -> usize = unsafe { std::mem::transmute::<usize, fn() -> usize>(f) };
        f()
    } else {
        0
    };
    report(removed);
    // SAFETY: ends the process at once, with no unwinding and no allocator.
    unsafe { libc::_exit(out_of_memory_status()) }
}

/// A fixed line buffer for [`out_of_memory`] (no heap).
struct Line {
    buf: [u8; 256],
    len: usize,
}

impl Default for Line {
    fn default() -> Self {
        Line {
            buf: [0; 256],
            len: 0,
        }
    }
}

impl Line {
    fn push(&mut self, s: &[u8]) {
        let n = s.len().min(self.buf.len() - self.len);
        self.buf[self.len..self.len + n].copy_from_slice(&s[..n]);
        self.len += n;
    }

    /// `size` in the units [`mib`] uses: MiB from 1 MiB up, else bytes.
    fn push_size(&mut self, size: usize) {
        let (n, unit): (usize, &[u8]) = if size >= 1 << 20 {
            ((size + (1 << 19)) >> 20, b" MiB")
        } else {
            (size, b" bytes")
        };
        let mut digits = [0u8; 20];
        let mut k = digits.len();
        let mut n = n;
        loop {
            k -= 1;
            digits[k] = b'0' + (n % 10) as u8;
            n /= 10;
            if n == 0 {
                break;
            }
        }
        self.push(&digits[k..]);
        self.push(unit);
    }
}

/// The error of a buffer the system refused: names what it was for and its size.
fn refused(what: &str, bytes: u64) -> io::Error {
    io::Error::new(
        io::ErrorKind::OutOfMemory,
        format!(
            "{what}: out of memory: {} could not be allocated (free memory, ulimit -v and the cgroup limit)",
            mib(bytes)
        ),
    )
}

/// A copy of `src`, reserved fallibly: a refusal is an error naming `what`.
pub fn try_copy<T: Copy>(src: &[T], what: &str) -> io::Result<Vec<T>> {
    let mut v = Vec::new();
    fallibly(|| v.try_reserve_exact(src.len()))
        .map_err(|_| refused(what, size_of_val(src) as u64))?;
    v.extend_from_slice(src);
    Ok(v)
}

/// Reserve room for `additional` more elements in `v` with `try_reserve_exact`: a
/// refusal is an error naming `what`.
pub fn try_reserve<T>(v: &mut Vec<T>, additional: usize, what: &str) -> io::Result<()> {
    fallibly(|| v.try_reserve_exact(additional)).map_err(|_| {
        refused(
            what,
            (additional as u64).saturating_mul(size_of::<T>() as u64),
        )
    })
}

/// `n` zeroed values, allocated zeroed (so the system's fresh pages are not written to
/// first: they are faulted in by whoever fills them) and fallibly: a refusal is an error
/// naming `what`.
pub fn try_zeroed<T: bytemuck::Zeroable>(n: usize, what: &str) -> io::Result<Vec<T>> {
    let layout = Layout::array::<T>(n)
        .map_err(|_| refused(what, (n as u64).saturating_mul(size_of::<T>() as u64)))?;
    if layout.size() == 0 {
        return Ok((0..n).map(|_| T::zeroed()).collect());
    }
    // SAFETY: `layout` has a non-zero size.
    let p = fallibly(|| unsafe { std::alloc::alloc_zeroed(layout) });
    if p.is_null() {
        return Err(refused(what, layout.size() as u64));
    }
    // SAFETY: `p` is a zeroed block of the global allocator with `Vec<T>`'s layout for
    // capacity `n`, and all-zero bytes are a valid `T` (`Zeroable`).
    Ok(unsafe { Vec::from_raw_parts(p.cast::<T>(), n, n) })
}

/// Print a refusal as the one `error: ...` line every command ends with (a closed stderr
/// is not an error). Written here, not through `output`: `mem` sits below every layer that
/// allocates, `scene` and `render` included, which never import `output`.
fn print_error(e: &dyn std::fmt::Display) {
    use std::io::Write;
    let _ = writeln!(std::io::stderr().lock(), "error: {e}");
}

/// `n` values not yet written, reserved fallibly as [`zeroed_or_exit`] reserves them (a
/// refusal exits the same way): for a buffer whose users write it all before reading it,
/// on the threads that will read it.
pub fn uninit_or_exit<T>(n: usize, what: &str) -> Vec<std::mem::MaybeUninit<T>> {
    let mut v = Vec::new();
    if let Err(e) = try_reserve(&mut v, n, what) {
        exit_after(|_| print_error(&e));
    }
    // SAFETY: the capacity is at least `n` (reserved above), and a `MaybeUninit` needs no
    // initialisation.
    unsafe { v.set_len(n) };
    v
}

/// [`try_zeroed`] where the caller cannot return an error (the planes of `render::render`,
/// whose callers' memory check has passed): a refusal is reported as [`Guarded`] reports
/// one, naming `what`, and the process exits with the status of
/// [`set_out_of_memory_status`].
pub fn zeroed_or_exit<T: bytemuck::Zeroable>(n: usize, what: &str) -> Vec<T> {
    match try_zeroed(n, what) {
        Ok(v) => v,
        Err(e) => exit_after(|_| print_error(&e)),
    }
}
