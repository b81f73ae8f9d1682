//! Small shared helpers with no domain knowledge: a seeded random generator, descriptive
//! statistics, and the progress/cancellation hook of long computations.

pub mod decimal;
pub mod monitor;
pub mod parts;
pub mod rng;
pub mod serde_num;
pub mod stats;

pub use monitor::{Monitor, NoMonitor, SubMonitor};
pub use rng::Rng;
pub use stats::Summary;

/// A time as calibd writes it everywhere (RFC 3339, UTC, milliseconds), e.g.
/// `2026-11-28T03:14:15.926Z`.
pub fn format_time(t: chrono::DateTime<chrono::Utc>) -> String {
    t.to_rfc3339_opts(chrono::SecondsFormat::Millis, true)
}

/// Give memory freed after a large job or upload back to the operating system. glibc's
/// allocator keeps freed pages in its arenas (a daemon that once parsed a 15 MB table would
/// hold them for good); `malloc_trim` returns them. No-op elsewhere.
pub fn release_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: malloc_trim only walks the allocator's own free lists; it takes no pointer.
    unsafe {
        libc::malloc_trim(0);
    }
}

/// Make large buffers (request bodies, tables) come from their own mappings, returned to the
/// system when freed, instead of from glibc's heap, whose dynamic threshold otherwise rises
/// to 32 MiB after the first large free and keeps such buffers in the heap for good. Called
/// once by the daemon at start. No-op elsewhere.
pub fn tune_allocator() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt sets an allocator parameter; it takes no pointer.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 1 << 20);
    }
}
