//! The command line's choice flags, each a closed set with the spellings scripts use: clap lists
//! the possible values in `--help` and refuses any other with the list. The rest of the program
//! reads each choice by its spelling ([`Choice::id`]).

use clap::ValueEnum;

/// The spelling of a choice, as typed on the command line.
pub trait Choice: ValueEnum {
    /// The spelling (`sim-match`, `busy`, ...).
    fn id(&self) -> &'static str;
}

macro_rules! choices {
    ($(#[$doc:meta] $name:ident { $($(#[$vdoc:meta])* $var:ident = $s:literal),+ $(,)? })+) => {
        $(
            #[$doc]
            #[derive(ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
            pub enum $name {
                $($(#[$vdoc])* #[value(name = $s)] $var),+
            }

            impl Choice for $name {
                fn id(&self) -> &'static str {
                    match self {
                        $($name::$var => $s),+
                    }
                }
            }
        )+
    };
}

choices! {
    /// `--mode`: how the two processes keep time.
    ModeArg {
        /// Paced by the clock, one cycle per period.
        Realtime = "realtime",
        /// Each cycle waits for the other process (deterministic, as fast as it goes).
        Lockstep = "lockstep",
    }
    /// `--wait`: how a process waits for the next message.
    WaitArg {
        /// Spin on the port.
        Busy = "busy",
        /// Sleep on an event.
        Block = "block",
        /// Spin briefly, then sleep.
        Hybrid = "hybrid",
    }
    /// `--stage`: a stage of an axis' controller chain.
    StageArg {
        /// The position loop.
        Position = "position",
        /// The feed-forward.
        Feedforward = "feedforward",
        /// The compensator.
        Compensator = "compensator",
        /// The velocity loop.
        Velocity = "velocity",
    }
    /// `identify inertia --method`.
    MethodArg {
        /// Method 1: match simulated deviation profiles.
        SimMatch = "sim-match",
        /// Method 2: linear interpolation between two known loads.
        Linear = "linear",
    }
    /// `identify inertia --deviation`.
    DeviationArg {
        /// Command minus load position.
        CommandLoad = "command-load",
        /// Motor position in load units minus load position.
        MotorLoad = "motor-load",
    }
    /// `identify stiffness --estimator`.
    EstimatorArg {
        /// Chosen from the data.
        Auto = "auto",
        /// The H1 estimator.
        H1 = "h1",
        /// The instrumental-variable estimator.
        Instrument = "instrument",
    }
    /// `identify stiffness --frf`.
    FrfArg {
        /// Motor torque to motor velocity.
        TorqueVelocity = "torque-velocity",
        /// Command to table (refused in closed loop, with the reason).
        CommandTable = "command-table",
    }
    /// `excite --kind`.
    ExciteKind {
        /// Random segments.
        RandomSegments = "random-segments",
        /// A pseudo-random binary sequence.
        Prbs = "prbs",
        /// A multisine.
        Multisine = "multisine",
    }
}

/// `--plugin ID` of `feedloop swap` without `--lib`: one of the built-in plugins, refused here
/// (naming the flag, the built-in ids and the closest one) before the loop is asked.
pub fn builtin_plugin(id: &str) -> anyhow::Result<()> {
    let known = feedloop_plugins::PLUGINS.iter().map(|e| e.id);
    if known.clone().any(|k| k == id) {
        return Ok(());
    }
    anyhow::bail!(
        "--plugin `{id}`: {}; a plugin of a shared library needs --lib FILE",
        feedloop_model::params::unknown_name_reason("plugin", id, known)
    )
}
