//! Offline learning of controller tables from simulated runs (never run by the scheduler): the
//! reversal pulses of `quadrant_compensator` ([`quadrant`]).

pub mod quadrant;
