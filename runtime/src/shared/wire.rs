//! The only types that cross the process boundary between the plant and the scheduler.
//!
//! Both are `#[repr(C)]`, fixed-size and travel zero-copy through iceoryx2 publish-subscribe.
//! Each carries an iceoryx2 `type_name` with a layout version: a process built with another
//! layout cannot open the service (`IncompatibleTypes`) instead of misreading bytes.
//! Units are SI; positions and velocities are in the axis' own units (see field docs).

use iceoryx2::prelude::ZeroCopySend;
use serde::{Deserialize, Serialize};

pub use feedloop_control::axis_io::{AxisCommand, AxisSensor};
pub use feedloop_model::MAX_AXES;

/// Protocol version checked in the start-up handshake (bump with any layout or meaning change).
pub const PROTOCOL_VERSION: u32 = 1;

/// `SensorSample::flags`: this sample is a handshake probe, not a cycle.
pub const FLAG_HELLO: u32 = 1;
/// `SensorSample::flags` / `ActuatorCommand::flags`: the sender is ending the run after this message.
pub const FLAG_END: u32 = 2;
/// `ActuatorCommand::flags`: the scheduler asks the plant for a controlled stop (operator stop).
pub const FLAG_STOP: u32 = 4;
/// `ActuatorCommand::flags`: a controller plugin failed (panicked); the plant makes a safe stop.
pub const FLAG_FAULT: u32 = 8;

/// One cycle's sensor sample, published by the plant.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[repr(C)]
pub struct SensorSample {
    /// Cycle number, 0-based; the command for this sample must echo it.
    pub seq: u64,
    /// Plant time at the sample, s (= seq * period).
    pub plant_time_s: f64,
    /// `PROTOCOL_VERSION` of the sender.
    pub protocol: u32,
    /// `FLAG_*` bits.
    pub flags: u32,
    /// Hash of the instance name (handshake check; see `instance_tag`).
    pub instance_tag: u64,
    /// Number of valid entries in `axes`.
    pub axis_count: u32,
    /// Deadline misses the plant has counted so far in this run (saturating); lets the scheduler's
    /// status service report them. Zero in the handshake. (Was `reserved`, always zero: same layout.)
    pub deadline_misses: u32,
    /// Cycles the plant woke more than half a period late (overruns) so far in this run, counted
    /// like `deadline_misses` over the cycles before this one (saturating). Zero in the handshake.
    pub plant_overruns: u32,
    /// Reserved, zero.
    pub reserved: u32,
    /// Per-axis measurements, in job axis order.
    pub axes: [AxisSensor; MAX_AXES],
}

/// One cycle's actuator command, published by the scheduler.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[repr(C)]
pub struct ActuatorCommand {
    /// Echo of the `SensorSample::seq` this command answers.
    pub seq: u64,
    /// `PROTOCOL_VERSION` of the sender.
    pub protocol: u32,
    /// `FLAG_*` bits.
    pub flags: u32,
    /// Hash of the instance name.
    pub instance_tag: u64,
    /// Number of valid entries in `axes`.
    pub axis_count: u32,
    /// Reserved, zero.
    pub reserved: u32,
    /// Per-axis commands, in job axis order.
    pub axes: [AxisCommand; MAX_AXES],
}

// SAFETY: both messages are `#[repr(C)]`, fixed-size and made only of integers, floats and
// arrays of such (`AxisSensor`, `AxisCommand` likewise): no pointers, no references, no drop
// glue, valid for any bit pattern the sender writes. Written by hand instead of derived because
// the per-axis parts live in the IPC-free `feedloop-control` crate. The type names carry the
// layout version.
unsafe impl ZeroCopySend for SensorSample {
    unsafe fn type_name() -> &'static str {
        "FeedloopSensorSampleV2"
    }
}

// SAFETY: as for `SensorSample` above.
unsafe impl ZeroCopySend for ActuatorCommand {
    unsafe fn type_name() -> &'static str {
        "FeedloopActuatorCommandV1"
    }
}

impl SensorSample {
    /// An all-zero sample for `axis_count` axes.
    pub const fn empty(axis_count: u32, instance_tag: u64) -> Self {
        Self {
            seq: 0,
            plant_time_s: 0.0,
            protocol: PROTOCOL_VERSION,
            flags: 0,
            instance_tag,
            axis_count,
            deadline_misses: 0,
            plant_overruns: 0,
            reserved: 0,
            axes: [AxisSensor {
                motor_pos: 0.0,
                motor_vel: 0.0,
                load_pos: 0.0,
                applied_torque: 0.0,
            }; MAX_AXES],
        }
    }
}

impl ActuatorCommand {
    /// A zero-torque command for `axis_count` axes.
    pub const fn empty(axis_count: u32, instance_tag: u64) -> Self {
        Self {
            seq: 0,
            protocol: PROTOCOL_VERSION,
            flags: 0,
            instance_tag,
            axis_count,
            reserved: 0,
            axes: [AxisCommand {
                torque: 0.0,
                reference: 0.0,
            }; MAX_AXES],
        }
    }
}

/// A wire message whose used part can be smaller than its fixed size: only the header and the
/// first `axis_count` axes carry data.
///
/// A receiver copies just that part out of shared memory ([`WireMessage::copy_used`]); the unused
/// tail stays zero. With two axes that is 2 of the sample's 5 cache lines and 1 of the command's
/// 3: lines the receiver never reads stay in the sender's cache, which shortens every round trip
/// between cores.
pub trait WireMessage: Copy {
    /// The header and the first `min(axis_count, MAX_AXES)` axes of `self`, the rest zero.
    #[inline]
    fn copy_used(&self) -> Self {
        let mut out = Self::zeroed();
        self.write_used(&mut out);
        out
    }
    /// A message of zeros (the starting point of a receiver's buffer).
    fn zeroed() -> Self;
    /// Writes the header and the first `min(axis_count, MAX_AXES)` axes of `self` into `dst`,
    /// leaving the rest of `dst` as it was: a sender that owns `dst`'s cache lines already
    /// touches only the lines a receiver reads.
    fn write_used(&self, dst: &mut Self);
}

/// Implements [`WireMessage`] for `$t`, whose header is the fields listed and whose axes follow
/// in `axes`, the first `axis_count` of them used.
macro_rules! wire_message {
    ($t:ident { $($field:ident),+ $(,)? }) => {
        impl WireMessage for $t {
            fn zeroed() -> Self {
                $t::empty(0, 0)
            }

            #[inline]
            fn write_used(&self, dst: &mut Self) {
                let n = (self.axis_count as usize).min(MAX_AXES);
                $(dst.$field = self.$field;)+
                dst.axes[..n].copy_from_slice(&self.axes[..n]);
            }
        }
    };
}

wire_message!(SensorSample {
    seq,
    plant_time_s,
    protocol,
    flags,
    instance_tag,
    axis_count,
    deadline_misses,
    plant_overruns,
    reserved,
});

wire_message!(ActuatorCommand {
    seq,
    protocol,
    flags,
    instance_tag,
    axis_count,
    reserved
});

/// A stable 64-bit tag of an instance name (FNV-1a), used to refuse cross-instance messages.
pub fn instance_tag(instance: &str) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for b in instance.bytes() {
        h ^= u64::from(b);
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    h
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wire_types_have_fixed_layout_without_padding_surprises() {
        assert_eq!(core::mem::size_of::<AxisSensor>(), 32);
        assert_eq!(core::mem::size_of::<SensorSample>(), 48 + 32 * MAX_AXES);
        assert_eq!(core::mem::size_of::<ActuatorCommand>(), 32 + 16 * MAX_AXES);
    }

    /// A sample of `axis_count` axes of instance tag 77 with the header figures given.
    fn sample(
        axis_count: u32,
        seq: u64,
        plant_time_s: f64,
        flags: u32,
        deadline_misses: u32,
    ) -> SensorSample {
        let mut s = SensorSample::empty(axis_count, 77);
        s.seq = seq;
        s.plant_time_s = plant_time_s;
        s.flags = flags;
        s.deadline_misses = deadline_misses;
        s
    }

    #[test]
    fn copy_used_keeps_the_header_and_the_used_axes_and_zeroes_the_rest() {
        let mut s = sample(3, 9, 0.5, FLAG_END, 4);
        s.plant_overruns = 6;
        for (i, a) in s.axes.iter_mut().enumerate() {
            a.motor_pos = i as f64 + 1.0;
            a.applied_torque = -(i as f64) - 1.0;
        }
        let c = s.copy_used();
        assert_eq!((c.seq, c.plant_time_s, c.flags), (9, 0.5, FLAG_END));
        assert_eq!(
            (
                c.instance_tag,
                c.axis_count,
                c.deadline_misses,
                c.plant_overruns
            ),
            (77, 3, 4, 6)
        );
        assert_eq!(c.axes[..3], s.axes[..3]);
        assert!(c.axes[3..].iter().all(|a| *a == AxisSensor::default()));
        // a full or an impossible axis count copies everything there is, without panicking
        s.axis_count = MAX_AXES as u32;
        assert_eq!(s.copy_used(), s);
        s.axis_count = u32::MAX;
        assert_eq!(s.copy_used(), s);

        let mut m = ActuatorCommand::empty(1, 5);
        m.seq = 3;
        m.flags = FLAG_STOP;
        m.axes[0].torque = 2.0;
        m.axes[1].torque = 7.0;
        let c = m.copy_used();
        assert_eq!(
            (c.seq, c.flags, c.instance_tag, c.axis_count),
            (3, FLAG_STOP, 5, 1)
        );
        assert_eq!(c.axes[0].torque, 2.0);
        assert_eq!(c.axes[1].torque, 0.0);
    }

    #[test]
    fn write_used_overwrites_the_header_and_the_used_axes_and_leaves_the_rest() {
        let mut s = sample(2, 12, 1.25, FLAG_HELLO, 3);
        s.axes[0].motor_pos = 1.0;
        s.axes[1].load_pos = -2.0;
        s.axes[2].motor_vel = 9.0; // beyond axis_count: not sent
        let mut dst = SensorSample::empty(5, 1);
        dst.axes[1].motor_vel = 4.0;
        dst.axes[3].applied_torque = 8.0;
        s.write_used(&mut dst);
        // what a receiver reads of it is exactly what it would read of `s`
        assert_eq!(dst.copy_used(), s.copy_used());
        assert_eq!(dst.axes[..2], s.axes[..2]);
        assert_eq!(dst.axes[3].applied_torque, 8.0);
        assert_eq!(dst.axes[2].motor_vel, 0.0);

        let mut m = ActuatorCommand::empty(1, 5);
        m.seq = 4;
        m.flags = FLAG_FAULT;
        m.axes[0].torque = -3.0;
        let mut d = ActuatorCommand::empty(8, 0);
        d.axes[0].reference = 6.0;
        d.axes[5].torque = 1.0;
        m.write_used(&mut d);
        assert_eq!(d.copy_used(), m.copy_used());
        assert_eq!(d.axes[0], m.axes[0]);
        assert_eq!(d.axes[5].torque, 1.0);
        // an impossible axis count writes everything there is, without panicking
        m.axis_count = u32::MAX;
        m.write_used(&mut d);
        assert_eq!(d, m);
    }

    #[test]
    fn instance_tags_differ_for_different_names() {
        assert_ne!(instance_tag("a"), instance_tag("b"));
        assert_eq!(instance_tag("cell-1"), instance_tag("cell-1"));
    }
}
