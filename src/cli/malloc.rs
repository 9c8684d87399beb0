//! glibc malloc settings for the process (Linux with glibc; elsewhere nothing): set before
//! the process starts threads of its own, unless the matching `MALLOC_*` variable sets them.

/// Buffers this large or larger are mapped on their own and given back to the system when
/// freed. glibc's own threshold rises to the largest buffer freed so far (up to 32 MiB), after
/// which full-size images come from the arenas, whose freed memory stays resident and
/// scattered: a large job's resident memory stood well above its heap (docs/history.md,
/// "Memory of one job").
#[cfg(all(target_os = "linux", target_env = "gnu"))]
const MAPPED_FROM: libc::c_int = 1 << 20;

/// Maps large buffers on their own ([`MAPPED_FROM`]), unless `MALLOC_MMAP_THRESHOLD_` sets the
/// threshold. For every command: the pipeline's images are the large ones.
pub fn map_large_buffers() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    if std::env::var_os("MALLOC_MMAP_THRESHOLD_").is_none() {
        // SAFETY: mallopt only sets a threshold that later allocations read.
        unsafe {
            libc::mallopt(libc::M_MMAP_THRESHOLD, MAPPED_FROM);
        }
    }
}

/// Caps glibc's malloc arenas at one per core, unless `MALLOC_ARENA_MAX` sets them.
///
/// glibc gives each new thread an arena of its own while fewer than 8 per core exist, and
/// each arena keeps its own high water of freed memory. A service process has many threads
/// (three runtimes and their blocking pools), so its heap crept under the chaos harness
/// (docs/history.md, "Malloc arenas"). One per core is enough for the pipeline's threads (one
/// per core) not to wait for each other.
pub fn limit_arenas() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    if std::env::var_os("MALLOC_ARENA_MAX").is_none() {
        let arenas = libc::c_int::try_from(arena_limit()).unwrap_or(libc::c_int::MAX);
        // SAFETY: mallopt only sets a limit that later allocations read; it is called before
        // this process starts any thread of its own.
        unsafe {
            libc::mallopt(libc::M_ARENA_MAX, arenas);
        }
    }
}

/// One arena per core, at least two (the main one and one for all other threads).
#[cfg(all(target_os = "linux", target_env = "gnu"))]
fn arena_limit() -> usize {
    std::thread::available_parallelism()
        .map_or(1, |n| n.get())
        .max(2)
}

#[cfg(all(test, target_os = "linux", target_env = "gnu"))]
mod tests {
    use super::{arena_limit, limit_arenas, map_large_buffers};

    /// The malloc arenas of this process, from glibc's own report.
    fn malloc_arenas() -> usize {
        let mut buffer = std::ptr::null_mut();
        let mut size = 0;
        // SAFETY: glibc writes the report into a buffer it allocates, read and freed here.
        unsafe {
            let stream = libc::open_memstream(&mut buffer, &mut size);
            assert!(!stream.is_null());
            libc::malloc_info(0, stream);
            libc::fclose(stream);
            let report = std::ffi::CStr::from_ptr(buffer)
                .to_string_lossy()
                .into_owned();
            libc::free(buffer.cast());
            report.matches("<heap nr=").count()
        }
    }

    #[test]
    fn many_threads_alive_at_once_make_no_more_arenas_than_cores() {
        limit_arenas();
        let before = malloc_arenas();
        let threads = 16;
        let all_allocated = std::sync::Barrier::new(threads);
        std::thread::scope(|scope| {
            for _ in 0..threads {
                scope.spawn(|| {
                    let block = std::hint::black_box(vec![1u8; 4096]);
                    all_allocated.wait();
                    drop(block);
                });
            }
        });
        // Without the limit each of the threads alive together takes an arena of its own.
        assert!(
            malloc_arenas() <= before.max(arena_limit()),
            "{} arenas",
            malloc_arenas()
        );
    }

    #[test]
    fn a_large_buffer_is_mapped_even_after_a_larger_one_was_freed() {
        map_large_buffers();
        // SAFETY: mallinfo2 only reads malloc's counters.
        let mapped = || unsafe { libc::mallinfo2() }.hblkhd;
        // Freeing a mapped 16 MiB block would raise glibc's own threshold to 16 MiB.
        drop(std::hint::black_box(vec![1u8; 16 << 20]));
        let before = mapped();
        let block = std::hint::black_box(vec![1u8; 4 << 20]);
        assert!(mapped() >= before + (4 << 20), "{} bytes mapped", mapped());
        drop(block);
    }
}
