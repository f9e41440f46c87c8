//! Real-time practice for the two processes: lock memory, pre-fault the stack, optional
//! SCHED_FIFO priority and CPU pinning. Each step falls back gracefully when not permitted and
//! reports what was actually applied.

use serde::Serialize;

/// What to try.
#[derive(Debug, Clone, Default)]
pub struct RtRequest {
    /// Lock all current and future pages in memory.
    pub mlockall: bool,
    /// SCHED_FIFO priority (1..99); `None` keeps the normal scheduler. Refused together with an
    /// unbounded busy wait (real-time throttling would stall the core).
    pub fifo_priority: Option<i32>,
    /// CPU to pin this process to.
    pub cpu: Option<usize>,
}

/// What was applied, for reports (`realtime` in latency.json).
#[derive(Debug, Clone, Default, Serialize, PartialEq)]
pub struct RtApplied {
    /// mlockall succeeded.
    pub mlockall: bool,
    /// SCHED_FIFO is in force.
    pub sched_fifo: bool,
    /// CPUs this process is pinned to (empty: not pinned).
    pub pinned: Vec<usize>,
    /// Why something requested was not applied.
    pub notes: Vec<String>,
}

/// Applies `req` to the calling process/thread.
pub fn apply(req: &RtRequest) -> RtApplied {
    let mut out = RtApplied::default();
    if req.mlockall {
        // SAFETY: plain syscall.
        let r = unsafe { libc::mlockall(libc::MCL_CURRENT | libc::MCL_FUTURE) };
        if r == 0 {
            out.mlockall = true;
            prefault_stack();
        } else {
            out.notes
                .push(format!("mlockall: {}", std::io::Error::last_os_error()));
        }
    }
    if let Some(cpu) = req.cpu {
        // SAFETY: cpu_set_t is plain data; the calls only read/write it.
        let ok = unsafe {
            let mut set: libc::cpu_set_t = std::mem::zeroed();
            libc::CPU_ZERO(&mut set);
            libc::CPU_SET(cpu, &mut set);
            libc::sched_setaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &set) == 0
        };
        if ok {
            out.pinned.push(cpu);
        } else {
            out.notes.push(format!(
                "pin to CPU {cpu}: {}",
                std::io::Error::last_os_error()
            ));
        }
    }
    if let Some(prio) = req.fifo_priority {
        let param = libc::sched_param {
            sched_priority: prio.clamp(1, 99),
        };
        // SAFETY: plain syscall with a valid sched_param.
        let r = unsafe { libc::sched_setscheduler(0, libc::SCHED_FIFO, &param) };
        if r == 0 {
            out.sched_fifo = true;
        } else {
            out.notes.push(format!(
                "SCHED_FIFO {prio}: {}",
                std::io::Error::last_os_error()
            ));
        }
    }
    out
}

/// Touches 256 KiB of stack so later cycles do not page-fault on it.
#[inline(never)]
fn prefault_stack() {
    let mut buf = [0u8; 256 * 1024];
    for i in (0..buf.len()).step_by(4096) {
        // SAFETY: in-bounds volatile write, only to force the page in.
        unsafe { std::ptr::write_volatile(&mut buf[i], 1) };
    }
    std::hint::black_box(&buf);
}

/// Resident set size of this process, bytes (from /proc/self/statm), if readable.
pub fn resident_bytes() -> Option<u64> {
    let s = std::fs::read_to_string("/proc/self/statm").ok()?;
    let pages: u64 = s.split_whitespace().nth(1)?.parse().ok()?;
    // SAFETY: sysconf is always safe to call.
    let page = unsafe { libc::sysconf(libc::_SC_PAGESIZE) };
    Some(pages * page.max(1) as u64)
}

/// Peak resident set size of this process, bytes (VmHWM).
pub fn peak_resident_bytes() -> Option<u64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = s.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}
