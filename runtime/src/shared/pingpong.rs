//! The floor the loop's round trip is measured against (issue 18): a bare iceoryx2 ping-pong of
//! the loop's own wire types, through the same endpoints ([`crate::shared::ipc`]), between two
//! processes. The pinging side publishes a [`SensorSample`] and spins until the echoing side's
//! [`ActuatorCommand`] with the same `seq` is back; the echo does nothing else. The round trip
//! is timed exactly as the plant times the loop's (just before the publish to the moment the
//! matching command is held), so the loop's extra time over it is what the loop adds: the
//! scheduler's chain, its bookkeeping, the recorders and what the plant does in between.
//!
//! Two paces: back to back (each ping as soon as the last echo is back: caches warm, the floor
//! of the transport) and at the loop's period (each ping at the start of a period, like the
//! plant: what a periodic loop can hope for).

use std::time::Duration;

use super::clock::{now_ns, spin_until_ns};
use super::ipc::{plant_endpoint, scheduler_endpoint, IpcError, WaitOutcome};
use super::wire::{ActuatorCommand, SensorSample, FLAG_END};
use feedloop_model::job::WaitKind;

/// Round trips measured by [`ping`], ns.
#[derive(Debug, Clone, Default)]
pub struct PingPong {
    /// Back to back.
    pub back_to_back_ns: Vec<u64>,
    /// One per period, started at the period's beginning.
    pub paced_ns: Vec<u64>,
}

/// Pings taken before the measured ones (caches, page faults, the first loans).
const WARM_UP: u64 = 2_000;

/// The pinging side on `instance`: waits up to `peer_timeout` for the echo, then measures
/// `back_to_back` round trips, then `paced` ones, one every `period_ns`; the samples carry
/// `axis_count` axes (the loop's size). Ends the echo with `FLAG_END`.
pub fn ping(
    instance: &str,
    axis_count: u32,
    back_to_back: u64,
    paced: u64,
    period_ns: u64,
    peer_timeout: Duration,
) -> Result<PingPong, IpcError> {
    let ep = plant_endpoint(instance, WaitKind::Busy, Duration::ZERO)?;
    let give_up = now_ns().saturating_add(peer_timeout.as_nanos() as u64);
    while !ep.peer_connected() {
        if now_ns() > give_up {
            return Err(IpcError::Receive(format!(
                "the ping-pong echo of instance `{instance}` did not connect within {peer_timeout:?}"
            )));
        }
        std::thread::sleep(Duration::from_millis(1));
    }
    let mut sample = SensorSample::empty(axis_count, 0);
    let mut seq = 0u64;
    let mut one = |sample: &mut SensorSample| -> Result<u64, IpcError> {
        sample.seq = seq;
        seq += 1;
        let t0 = now_ns();
        ep.send(*sample)?;
        let deadline = t0.saturating_add(1_000_000_000);
        loop {
            match ep.receive_until(deadline)? {
                WaitOutcome::Got(c) if c.seq == sample.seq => return Ok(now_ns() - t0),
                WaitOutcome::Got(_) => {}
                WaitOutcome::TimedOut => {
                    return Err(IpcError::Receive(format!(
                        "the ping-pong echo did not answer ping {} within 1 s",
                        sample.seq
                    )))
                }
            }
        }
    };
    for _ in 0..WARM_UP {
        one(&mut sample)?;
    }
    let mut out = PingPong {
        back_to_back_ns: Vec::with_capacity(back_to_back as usize),
        paced_ns: Vec::with_capacity(paced as usize),
    };
    for _ in 0..back_to_back {
        out.back_to_back_ns.push(one(&mut sample)?);
    }
    let mut next = now_ns().saturating_add(period_ns);
    for _ in 0..paced {
        spin_until_ns(next);
        next = next.saturating_add(period_ns);
        out.paced_ns.push(one(&mut sample)?);
    }
    sample.flags = FLAG_END;
    sample.seq = seq;
    ep.send(sample)?;
    Ok(out)
}

/// The echoing side on `instance`: answers each sample with a command of the same `seq` and
/// size until a sample carries `FLAG_END` (returns the count answered) or none comes for
/// `idle_timeout`.
pub fn echo(instance: &str, idle_timeout: Duration) -> Result<u64, IpcError> {
    let ep = scheduler_endpoint(instance, WaitKind::Busy, Duration::ZERO)?;
    let mut answered = 0u64;
    loop {
        let deadline = now_ns().saturating_add(idle_timeout.as_nanos() as u64);
        match ep.receive_until(deadline)? {
            WaitOutcome::Got(s) => {
                if s.flags & FLAG_END != 0 {
                    return Ok(answered);
                }
                let mut c = ActuatorCommand::empty(s.axis_count, s.instance_tag);
                c.seq = s.seq;
                ep.send(c)?;
                answered += 1;
            }
            WaitOutcome::TimedOut => {
                return Err(IpcError::Receive(format!(
                    "the ping-pong echo of instance `{instance}` heard nothing for {idle_timeout:?}"
                )))
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_ping_pong_between_two_threads_answers_every_ping_in_order() {
        let instance = format!("pptest{}", std::process::id());
        let i2 = instance.clone();
        let e = std::thread::spawn(move || echo(&i2, Duration::from_secs(10)));
        let p = ping(&instance, 2, 500, 50, 200_000, Duration::from_secs(10)).unwrap();
        assert_eq!(p.back_to_back_ns.len(), 500);
        assert_eq!(p.paced_ns.len(), 50);
        assert!(p.back_to_back_ns.iter().all(|t| *t > 0));
        assert_eq!(e.join().unwrap().unwrap(), WARM_UP + 550);
    }
}
