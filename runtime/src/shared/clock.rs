//! Monotonic time in nanoseconds and absolute-deadline waits (CLOCK_MONOTONIC).

/// Nanoseconds on CLOCK_MONOTONIC.
#[inline]
pub fn now_ns() -> u64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: clock_gettime writes into the timespec we own; CLOCK_MONOTONIC always exists on Linux.
    unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) };
    ts.tv_sec as u64 * 1_000_000_000 + ts.tv_nsec as u64
}

/// Sleeps until the absolute monotonic time `deadline_ns` (returns at once if it has passed).
pub fn sleep_until_ns(deadline_ns: u64) {
    let ts = libc::timespec {
        tv_sec: (deadline_ns / 1_000_000_000) as libc::time_t,
        tv_nsec: (deadline_ns % 1_000_000_000) as libc::c_long,
    };
    loop {
        // SAFETY: plain syscall with a valid timespec; a null remainder is allowed with TIMER_ABSTIME.
        let r = unsafe {
            libc::clock_nanosleep(
                libc::CLOCK_MONOTONIC,
                libc::TIMER_ABSTIME,
                &ts,
                std::ptr::null_mut(),
            )
        };
        if r != libc::EINTR {
            return;
        }
    }
}

/// Spins until `deadline_ns`.
#[inline]
pub fn spin_until_ns(deadline_ns: u64) {
    while now_ns() < deadline_ns {
        std::hint::spin_loop();
    }
}

/// Waits until `deadline_ns`: sleeping until `spin_ns` before it, then spinning.
/// `spin_ns = 0` sleeps all the way; `u64::MAX` spins all the way.
pub fn wait_until_ns(deadline_ns: u64, spin_ns: u64) {
    let sleep_to = deadline_ns.saturating_sub(spin_ns);
    if spin_ns != u64::MAX && now_ns() < sleep_to {
        sleep_until_ns(sleep_to);
    }
    spin_until_ns(deadline_ns);
}

/// CPU time consumed by the calling process, s.
pub fn process_cpu_s() -> f64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: as above.
    unsafe { libc::clock_gettime(libc::CLOCK_PROCESS_CPUTIME_ID, &mut ts) };
    ts.tv_sec as f64 + ts.tv_nsec as f64 * 1e-9
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sleeping_until_a_deadline_does_not_return_early() {
        let d = now_ns() + 2_000_000;
        sleep_until_ns(d);
        assert!(now_ns() >= d);
        let d = now_ns() + 200_000;
        wait_until_ns(d, 100_000);
        assert!(now_ns() >= d);
    }
}
