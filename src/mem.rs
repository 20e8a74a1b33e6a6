//! Memory hints for the large buffers of a render: output planes, prepared cylinders, the
//! scene file's bytes and its cylinder list. Used by every stage, so it belongs to none.

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
