//! Counts of GPU work, kept in every build (relaxed atomics, a few nanoseconds each):
//! buffers and bind groups created, compute dispatches recorded, queue submissions and
//! readbacks with their bytes. Every creation, dispatch, submission and readback of the
//! crate goes through [`GpuContext`](super::GpuContext)'s helpers, which count here, so
//! `unica bench --live` can show what one generated frame costs the CPU.

use std::sync::atomic::{AtomicU64, Ordering};

/// The running counters of one device (shared by clones of its context).
#[derive(Debug, Default)]
pub struct Counters {
    buffers: AtomicU64,
    bind_groups: AtomicU64,
    dispatches: AtomicU64,
    submissions: AtomicU64,
    readbacks: AtomicU64,
    readback_bytes: AtomicU64,
}

/// A snapshot of [`Counters`]; the difference of two is the work between them.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Counts {
    pub buffers: u64,
    pub bind_groups: u64,
    pub dispatches: u64,
    pub submissions: u64,
    pub readbacks: u64,
    pub readback_bytes: u64,
}

impl Counters {
    pub(crate) fn buffer(&self) {
        self.buffers.fetch_add(1, Ordering::Relaxed);
    }

    pub(crate) fn bind_group(&self) {
        self.bind_groups.fetch_add(1, Ordering::Relaxed);
    }

    pub(crate) fn dispatches(&self, count: u64) {
        self.dispatches.fetch_add(count, Ordering::Relaxed);
    }

    pub(crate) fn submission(&self) {
        self.submissions.fetch_add(1, Ordering::Relaxed);
    }

    pub(crate) fn readback(&self, bytes: u64) {
        self.readbacks.fetch_add(1, Ordering::Relaxed);
        self.readback_bytes.fetch_add(bytes, Ordering::Relaxed);
    }

    pub fn snapshot(&self) -> Counts {
        let get = |c: &AtomicU64| c.load(Ordering::Relaxed);
        Counts {
            buffers: get(&self.buffers),
            bind_groups: get(&self.bind_groups),
            dispatches: get(&self.dispatches),
            submissions: get(&self.submissions),
            readbacks: get(&self.readbacks),
            readback_bytes: get(&self.readback_bytes),
        }
    }
}

impl std::ops::Sub for Counts {
    type Output = Counts;

    fn sub(self, earlier: Counts) -> Counts {
        Counts {
            buffers: self.buffers - earlier.buffers,
            bind_groups: self.bind_groups - earlier.bind_groups,
            dispatches: self.dispatches - earlier.dispatches,
            submissions: self.submissions - earlier.submissions,
            readbacks: self.readbacks - earlier.readbacks,
            readback_bytes: self.readback_bytes - earlier.readback_bytes,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counts_add_up_and_differences_are_the_work_between() {
        let c = Counters::default();
        c.buffer();
        let before = c.snapshot();
        c.buffer();
        c.bind_group();
        c.dispatches(5);
        c.submission();
        c.readback(256);
        c.readback(16);
        let d = c.snapshot() - before;
        assert_eq!(
            d,
            Counts {
                buffers: 1,
                bind_groups: 1,
                dispatches: 5,
                submissions: 1,
                readbacks: 2,
                readback_bytes: 272,
            }
        );
    }
}
