//! Memory hints for the large buffers of a render: output planes, prepared cylinders, the
//! scene file's bytes and its cylinder list, and the allocator's policy for them. Used by
//! every stage, so it belongs to none.

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

/// Keep the memory a process frees for its own later allocations, instead of returning
/// each large block to the kernel (glibc maps every block over 128 KiB on its own and
/// unmaps it when freed). A render frees the scene file's bytes before it allocates the
/// prepared cylinders, and the BVH build's scratch before the trace: reused, those pages
/// are already faulted in, where fresh ones cost a kernel fault and zeroing each (on the
/// virtual machines measured here about 1 ms per MiB: 10 of the 58 ms of a 16×16 render
/// of 100 000 cylinders). A policy for the whole process, so the command line sets it
/// once at start; other allocators than glibc's are left as they are.
pub fn keep_freed_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        // glibc's largest mmap threshold on 64-bit targets (larger values are refused).
        const MMAP_MAX: libc::c_int = 32 << 20;
        // SAFETY: `mallopt` only changes glibc's allocation policy for later allocations;
        // it is thread-safe, and a refused value leaves the policy as it was.
        unsafe {
            libc::mallopt(libc::M_MMAP_THRESHOLD, MMAP_MAX);
            libc::mallopt(libc::M_TRIM_THRESHOLD, libc::c_int::MAX);
        }
    }
}
