//! iceoryx2 services of one feedloop instance, and the waits both processes use.
//!
//! Services (all named per instance, so two instances on one PC never cross):
//! - `feedloop/<instance>/sensors`: [`SensorSample`], plant -> scheduler, one publisher.
//! - `feedloop/<instance>/commands`: [`ActuatorCommand`], scheduler -> plant, one publisher.
//! - `feedloop/<instance>/sensors_ready`, `.../commands_ready`: events that wake a blocked peer.
//!
//! The iceoryx2 configuration is built in code ([`iceoryx_config`]): it never depends on the
//! working directory or on config files lying around, so processes started from different
//! folders always meet.

use std::cell::Cell;
use std::time::Duration;

use crate::shared::clock::now_ns;

use iceoryx2::config::Config;
use iceoryx2::node::{Node, NodeBuilder};
use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use iceoryx2::sample_mut::SampleMut;

use crate::shared::wire::{ActuatorCommand, SensorSample, WireMessage};
use feedloop_model::job::WaitKind;

thread_local! {
    static IN_SEND: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
}

/// Whether the calling thread is inside an iceoryx2 loan/send of [`Endpoint::send`].
///
/// iceoryx2 0.10 allocates one small reference-counted block per loan (and frees it on send);
/// allocation-counting tests use this to tell those apart from feedloop's own allocations.
pub fn in_iceoryx_send() -> bool {
    IN_SEND.with(std::cell::Cell::get)
}

/// Errors setting up or using the services.
#[derive(Debug, thiserror::Error)]
pub enum IpcError {
    /// An instance name that cannot name a service.
    #[error(
        "invalid instance name `{0}`: use lowercase letters, digits, `_` and `-` (at most 64)"
    )]
    InvalidInstance(String),
    /// iceoryx2 refused to create a node, service or port.
    #[error("iceoryx2: cannot {what}: {detail}")]
    Setup {
        /// What was being created.
        what: String,
        /// iceoryx2's error.
        detail: String,
    },
    /// Sending failed.
    #[error("iceoryx2: send failed: {0}")]
    Send(String),
    /// Receiving failed.
    #[error("iceoryx2: receive failed: {0}")]
    Receive(String),
    /// The peer did not appear in time.
    #[error("the {peer} process of instance `{instance}` did not connect within {seconds:.1} s")]
    PeerTimeout {
        /// Which peer.
        peer: &'static str,
        /// Instance name.
        instance: String,
        /// How long we waited.
        seconds: f64,
    },
    /// The peer speaks another protocol or belongs to another instance.
    #[error("handshake refused: {0}")]
    Handshake(String),
}

fn setup_err(what: impl Into<String>, e: impl std::fmt::Debug) -> IpcError {
    IpcError::Setup {
        what: what.into(),
        detail: format!("{e:?}"),
    }
}

/// The iceoryx2 configuration used by every feedloop process (independent of the working
/// directory): default values with a feedloop-specific file prefix.
pub fn iceoryx_config() -> Config {
    let mut c = Config::default();
    if let Ok(prefix) = FileName::new(b"feedloop_") {
        c.global.prefix = prefix;
    }
    c
}

/// Creates a node (cleaning up resources of dead nodes on the way).
pub fn create_node(instance: &str, role: &str) -> Result<Node<ipc::Service>, IpcError> {
    if !feedloop_model::job::valid_name(instance, true) {
        return Err(IpcError::InvalidInstance(instance.to_string()));
    }
    set_log_level(LogLevel::Error);
    let name = NodeName::new(&format!("feedloop-{instance}-{role}"))
        .map_err(|e| setup_err("name the node", e))?;
    NodeBuilder::new()
        .name(&name)
        .config(&iceoryx_config())
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<ipc::Service>()
        .map_err(|e| setup_err("create a node", e))
}

fn service_name(instance: &str, leaf: &str) -> Result<ServiceName, IpcError> {
    ServiceName::new(&format!("feedloop/{instance}/{leaf}"))
        .map_err(|e| setup_err(format!("name service {leaf}"), e))
}

pub(crate) type PsFactory<T> =
    iceoryx2::service::port_factory::publish_subscribe::PortFactory<ipc::Service, T, ()>;
type EvFactory = iceoryx2::service::port_factory::event::PortFactory<ipc::Service>;

pub(crate) fn pubsub<T: std::fmt::Debug + ZeroCopySend>(
    node: &Node<ipc::Service>,
    instance: &str,
    leaf: &str,
) -> Result<PsFactory<T>, IpcError> {
    node.service_builder(&service_name(instance, leaf)?)
        .publish_subscribe::<T>()
        .max_publishers(1)
        .max_subscribers(4)
        .subscriber_max_buffer_size(4)
        .history_size(0)
        .enable_safe_overflow(true)
        .open_or_create()
        .map_err(|e| setup_err(format!("open service feedloop/{instance}/{leaf}"), e))
}

fn event(node: &Node<ipc::Service>, instance: &str, leaf: &str) -> Result<EvFactory, IpcError> {
    node.service_builder(&service_name(instance, leaf)?)
        .event()
        .max_notifiers(2)
        .max_listeners(4)
        .open_or_create()
        .map_err(|e| setup_err(format!("open event feedloop/{instance}/{leaf}"), e))
}

/// A message endpoint: publish `Out`, receive `In`, with events to wake a blocked peer.
pub struct Endpoint<
    Out: std::fmt::Debug + ZeroCopySend + 'static,
    In: std::fmt::Debug + ZeroCopySend + 'static,
> {
    publisher: Publisher<ipc::Service, Out, ()>,
    subscriber: Subscriber<ipc::Service, In, ()>,
    notifier: Notifier<ipc::Service>,
    listener: Listener<ipc::Service>,
    /// The next message's shared-memory sample, loaned and filled with the last message in the
    /// slack after a send (see [`Endpoint::send`]).
    next: Cell<Option<SampleMut<ipc::Service, Out, ()>>>,
    out_service: PsFactory<Out>,
    in_service: PsFactory<In>,
    wait: WaitKind,
    spin_ns: u64,
    /// Longest stretch without a poll while spinning in the last `receive_until`, ns.
    poll_gap_ns: Cell<u64>,
    /// Clock reading of the last poll of the last `receive_until`, ns.
    last_poll_ns: Cell<u64>,
    /// Clock reading at the start of the last `receive_until`, ns.
    wait_start_ns: Cell<u64>,
    /// Clock reading just before the last poll that found the queue empty, in the last
    /// `receive_until` (`None`: its message was there at the first poll).
    empty_poll_ns: Cell<Option<u64>>,
    // keep the node alive as long as the ports
    _node: Node<ipc::Service>,
}

/// The plant's endpoint.
pub type PlantEndpoint = Endpoint<SensorSample, ActuatorCommand>;
/// The scheduler's endpoint.
pub type SchedulerEndpoint = Endpoint<ActuatorCommand, SensorSample>;

/// Opens the plant's side of `instance`.
pub fn plant_endpoint(
    instance: &str,
    wait: WaitKind,
    spin: Duration,
) -> Result<PlantEndpoint, IpcError> {
    let node = create_node(instance, "plant")?;
    Endpoint::open(
        node,
        instance,
        ("sensors", "sensors_ready"),
        ("commands", "commands_ready"),
        wait,
        spin,
    )
}

/// Opens the scheduler's side of `instance`.
pub fn scheduler_endpoint(
    instance: &str,
    wait: WaitKind,
    spin: Duration,
) -> Result<SchedulerEndpoint, IpcError> {
    let node = create_node(instance, "scheduler")?;
    Endpoint::open(
        node,
        instance,
        ("commands", "commands_ready"),
        ("sensors", "sensors_ready"),
        wait,
        spin,
    )
}

/// Outcome of a bounded wait.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum WaitOutcome<T> {
    /// A message arrived.
    Got(T),
    /// The deadline passed first.
    TimedOut,
}

impl<Out, In> Endpoint<Out, In>
where
    Out: std::fmt::Debug + ZeroCopySend + WireMessage + 'static,
    In: std::fmt::Debug + ZeroCopySend + WireMessage + 'static,
{
    fn open(
        node: Node<ipc::Service>,
        instance: &str,
        out: (&str, &str),
        inp: (&str, &str),
        wait: WaitKind,
        spin: Duration,
    ) -> Result<Self, IpcError> {
        let spin_ns = spin.as_nanos().min(u64::MAX as u128) as u64;
        let out_service = pubsub::<Out>(&node, instance, out.0)?;
        let in_service = pubsub::<In>(&node, instance, inp.0)?;
        let publisher = out_service
            .publisher_builder()
            .create()
            .map_err(|e| setup_err(format!("create the publisher of {} (is another process of instance `{instance}` running?)", out.0), e))?;
        let subscriber = in_service
            .subscriber_builder()
            .create()
            .map_err(|e| setup_err(format!("create the subscriber of {}", inp.0), e))?;
        let notifier = event(&node, instance, out.1)?
            .notifier_builder()
            .create()
            .map_err(|e| setup_err(format!("create the notifier of {}", out.1), e))?;
        let listener = event(&node, instance, inp.1)?
            .listener_builder()
            .create()
            .map_err(|e| setup_err(format!("create the listener of {}", inp.1), e))?;
        Ok(Self {
            publisher,
            subscriber,
            notifier,
            listener,
            next: Cell::new(None),
            out_service,
            in_service,
            wait,
            spin_ns,
            poll_gap_ns: Cell::new(0),
            last_poll_ns: Cell::new(0),
            wait_start_ns: Cell::new(0),
            empty_poll_ns: Cell::new(None),
            _node: node,
        })
    }

    /// Whether the peer's ports are connected (its subscriber on our output, its publisher on our input).
    pub fn peer_connected(&self) -> bool {
        self.out_service.dynamic_config().number_of_subscribers() >= 1
            && self.in_service.dynamic_config().number_of_publishers() >= 1
    }

    /// Publishes `msg` and, for blocking/hybrid peers, notifies the event.
    ///
    /// If [`Endpoint::prepare_next`] ran since the last send, the shared-memory sample is
    /// already loaned and its cache lines are this core's: the send writes only the header and
    /// the used axes ([`WireMessage::write_used`]) and hands the sample over. Otherwise it
    /// loans one and writes the whole message.
    pub fn send(&self, msg: Out) -> Result<(), IpcError> {
        IN_SEND.with(|f| f.set(true));
        let sent = self.publish(msg);
        IN_SEND.with(|f| f.set(false));
        sent?;
        if self.wait != WaitKind::Busy {
            self.notifier
                .notify()
                .map_err(|e| IpcError::Send(format!("{e:?}")))?;
        }
        Ok(())
    }

    /// Loans the next message's sample and fills it with `template` (the message just sent),
    /// off the round trip: the plant calls it while its command is on the way, the scheduler
    /// in its slack. A failed loan is only retried by the next send.
    pub fn prepare_next(&self, template: &Out) {
        IN_SEND.with(|f| f.set(true));
        if let Ok(s) = self.publisher.loan_uninit() {
            // a sample still held is given back to the publisher by its drop
            self.next.set(Some(s.write_payload(*template)));
        }
        IN_SEND.with(|f| f.set(false));
    }

    #[inline]
    fn publish(&self, msg: Out) -> Result<(), IpcError> {
        let sample = match self.next.take() {
            Some(mut s) => {
                msg.write_used(s.payload_mut());
                s
            }
            None => self
                .publisher
                .loan_uninit()
                .map_err(|e| IpcError::Send(format!("{e:?}")))?
                .write_payload(msg),
        };
        sample
            .send()
            .map(|_| ())
            .map_err(|e| IpcError::Send(format!("{e:?}")))
    }

    /// Takes the next message if one is there (no waiting).
    #[inline]
    pub fn try_receive(&self) -> Result<Option<In>, IpcError> {
        let mut m = In::zeroed();
        Ok(self.try_receive_into(&mut m)?.then_some(m))
    }

    /// Copies the next message into `dst` if one is there (no waiting): its header and used
    /// axes ([`WireMessage::write_used`]), the rest of `dst` left as it was. `Ok(true)` when a
    /// message was copied.
    #[inline]
    pub fn try_receive_into(&self, dst: &mut In) -> Result<bool, IpcError> {
        match self.subscriber.receive() {
            Ok(Some(s)) => {
                s.payload().write_used(dst);
                Ok(true)
            }
            Ok(None) => Ok(false),
            Err(e) => Err(IpcError::Receive(format!("{e:?}"))),
        }
    }

    /// Waits for the next message until the monotonic time `deadline_ns` (see
    /// [`crate::shared::clock::now_ns`]), with this endpoint's wait strategy.
    pub fn receive_until(&self, deadline_ns: u64) -> Result<WaitOutcome<In>, IpcError> {
        let mut m = In::zeroed();
        Ok(match self.receive_until_into(deadline_ns, &mut m)? {
            WaitOutcome::Got(()) => WaitOutcome::Got(m),
            WaitOutcome::TimedOut => WaitOutcome::TimedOut,
        })
    }

    /// [`Endpoint::receive_until`] into `dst` ([`Endpoint::try_receive_into`]): no copy of
    /// the whole message on the way.
    pub fn receive_until_into(
        &self,
        deadline_ns: u64,
        dst: &mut In,
    ) -> Result<WaitOutcome<()>, IpcError> {
        let start = now_ns();
        let spin_until = match self.wait {
            WaitKind::Busy => deadline_ns,
            WaitKind::Block => start,
            WaitKind::Hybrid => start.saturating_add(self.spin_ns).min(deadline_ns),
        };
        // A spinning process polls every few hundred nanoseconds; a longer stretch between two
        // polls means the OS (or the hypervisor) took the core away. Kept for the caller's
        // records (`poll_gap_ns`), never acted upon here.
        self.wait_start_ns.set(start);
        let mut prev = start;
        let mut gap = 0u64;
        let mut empty = None;
        loop {
            if self.try_receive_into(dst)? {
                self.poll_gap_ns.set(gap);
                self.last_poll_ns.set(prev);
                self.empty_poll_ns.set(empty);
                return Ok(WaitOutcome::Got(()));
            }
            empty = Some(prev);
            let now = now_ns();
            gap = gap.max(now.saturating_sub(prev));
            prev = now;
            if now >= deadline_ns {
                self.poll_gap_ns.set(gap);
                self.last_poll_ns.set(prev);
                self.empty_poll_ns.set(empty);
                return Ok(WaitOutcome::TimedOut);
            }
            if now < spin_until {
                std::hint::spin_loop();
                continue;
            }
            // Block on the peer's event; a stale notification only costs one extra turn.
            let left = Duration::from_nanos(deadline_ns - now).min(Duration::from_millis(100));
            match self.listener.timed_wait(|_| {}, left) {
                Ok(_) => {}
                // A signal (e.g. an operator stop) interrupted the wait: look again; the caller
                // polls its stop flag between waits.
                Err(iceoryx2::port::listener::ListenerWaitError::InterruptSignal) => {}
                Err(e) => return Err(IpcError::Receive(format!("{e:?}"))),
            }
            // the time spent blocked was given away on purpose
            prev = now_ns();
        }
    }

    /// Clock reading just before the last poll of the last [`Endpoint::receive_until`] that
    /// found the queue empty; `None` when its message was already waiting at the first poll.
    /// A message held shortly after such a poll is the newest there (the peer publishes once a
    /// period); one that was waiting, or held long after it (a stall in between), may have newer
    /// ones queued behind it.
    pub fn empty_poll_ns(&self) -> Option<u64> {
        self.empty_poll_ns.get()
    }

    /// [`Endpoint::receive_until`] for long waits (start-up, handshake): gives up early, with
    /// `TimedOut`, once `stop` is set (looked at every 50 ms at least).
    pub fn receive_until_or_stop(
        &self,
        deadline_ns: u64,
        stop: &std::sync::atomic::AtomicBool,
    ) -> Result<WaitOutcome<In>, IpcError> {
        loop {
            let chunk_end = deadline_ns.min(now_ns().saturating_add(50_000_000));
            match self.receive_until(chunk_end)? {
                WaitOutcome::TimedOut
                    if now_ns() < deadline_ns
                        && !stop.load(std::sync::atomic::Ordering::Relaxed) => {}
                other => return Ok(other),
            }
        }
    }

    /// The longest time between two polls of the last [`Endpoint::receive_until`] while it
    /// spun, ns (time blocked in a wait excluded). Together with [`Endpoint::last_poll_ns`] it
    /// tells whether the process lost its core while waiting.
    pub fn poll_gap_ns(&self) -> u64 {
        self.poll_gap_ns.get()
    }

    /// Clock reading ([`crate::shared::clock::now_ns`]) of the last poll of the last
    /// [`Endpoint::receive_until`].
    pub fn last_poll_ns(&self) -> u64 {
        self.last_poll_ns.get()
    }

    /// Clock reading at the start of the last [`Endpoint::receive_until`].
    pub fn wait_start_ns(&self) -> u64 {
        self.wait_start_ns.get()
    }

    /// Drops any queued messages and event notifications.
    pub fn drain(&self) -> Result<(), IpcError> {
        while self.try_receive()?.is_some() {}
        let _ = self.listener.try_wait(|_| {});
        Ok(())
    }
}
