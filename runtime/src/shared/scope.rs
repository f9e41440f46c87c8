//! The scope feed: the blocks the recorders write, published for `feedloop scope`.
//!
//! Each process's recorder thread, after writing a block of cycle records to its log, publishes
//! the same records on `feedloop/<instance>/scope/plant` or `.../scope/scheduler` as one
//! [`ScopeBlock`]. The cycle's thread does nothing more than before; the writer thread runs in
//! the period's slack. A subscriber that is slow or absent costs the loop nothing: iceoryx2
//! keeps at most [`SUBSCRIBER_BLOCKS`] blocks per subscriber and overwrites the oldest (safe
//! overflow); the subscriber sees the loss as a gap in the cycle numbers and counts it.

use iceoryx2::node::Node;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use serde::de::DeserializeOwned;
use serde::Serialize;

use crate::shared::ipc::{create_node, IpcError};
use crate::shared::record::{Tap, TapFactory};
use feedloop_trace::log::{decode_records, encode_records, PlantRecord, SchedRecord};

/// Bytes of encoded records one block holds (a writer chunk of 64 plant records takes about
/// 23 kB with eight axes).
pub const SCOPE_BLOCK_BYTES: usize = 32 * 1024;
/// Blocks iceoryx2 queues per subscriber before it overwrites the oldest: at 10 kHz, with the
/// writer's blocks of about 20 records, about a quarter of a second of data.
pub const SUBSCRIBER_BLOCKS: usize = 128;
/// Layout version of [`ScopeBlock`] (also in its iceoryx2 type name).
pub const SCOPE_PROTOCOL: u32 = 1;

/// Which process a block comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u32)]
pub enum ScopeSource {
    /// The plant: what was measured and applied ([`PlantRecord`]).
    Plant = 0,
    /// The scheduler: what the chain commanded ([`SchedRecord`]).
    Scheduler = 1,
}

impl ScopeSource {
    fn leaf(self) -> &'static str {
        match self {
            ScopeSource::Plant => "scope/plant",
            ScopeSource::Scheduler => "scope/scheduler",
        }
    }
}

/// One block of cycle records, as the recorder wrote them to its log.
#[derive(Debug, Clone, Copy, ZeroCopySend)]
#[repr(C)]
#[type_name("FeedloopScopeBlockV1")]
pub struct ScopeBlock {
    /// [`SCOPE_PROTOCOL`] of the sender.
    pub protocol: u32,
    /// [`ScopeSource`] as a number.
    pub source: u32,
    /// Records in the block.
    pub count: u32,
    /// Valid bytes in `bytes`.
    pub len: u32,
    /// Identifies the run (the publishing process's start on the monotonic clock, ns): a new
    /// value means the loop was restarted.
    pub run_id: u64,
    /// Control period, ns.
    pub period_ns: u64,
    /// Axes in the job.
    pub axis_count: u32,
    /// Number of this block in its run (wrapping): a gap tells a subscriber it lost blocks.
    pub block: u32,
    /// Records the recorder's ring dropped so far in this run (the log lacks them too).
    pub ring_dropped: u64,
    /// The records, in the log's encoding ([`encode_records`]).
    pub bytes: [u8; SCOPE_BLOCK_BYTES],
}

type BlockFactory =
    iceoryx2::service::port_factory::publish_subscribe::PortFactory<ipc::Service, ScopeBlock, ()>;

fn service(
    node: &Node<ipc::Service>,
    instance: &str,
    src: ScopeSource,
) -> Result<BlockFactory, IpcError> {
    let name = ServiceName::new(&format!("feedloop/{instance}/{}", src.leaf())).map_err(|e| {
        IpcError::Setup {
            what: format!("name service {}", src.leaf()),
            detail: format!("{e:?}"),
        }
    })?;
    node.service_builder(&name)
        .publish_subscribe::<ScopeBlock>()
        .max_publishers(1)
        .max_subscribers(2)
        .subscriber_max_buffer_size(SUBSCRIBER_BLOCKS)
        .history_size(0)
        .enable_safe_overflow(true)
        .open_or_create()
        .map_err(|e| IpcError::Setup {
            what: format!("open service feedloop/{instance}/{}", src.leaf()),
            detail: format!("{e:?}"),
        })
}

/// The publishing side, owned by a recorder's writer thread.
struct ScopePublisher {
    publisher: Publisher<ipc::Service, ScopeBlock, ()>,
    service: BlockFactory,
    _node: Node<ipc::Service>,
    block: Box<ScopeBlock>,
}

impl ScopePublisher {
    fn open(
        instance: &str,
        src: ScopeSource,
        period_ns: u64,
        axis_count: u32,
    ) -> Result<Self, IpcError> {
        let node = create_node(
            instance,
            &format!("{}-scope", src.leaf().replace("scope/", "")),
        )?;
        let service = service(&node, instance, src)?;
        let publisher = service
            .publisher_builder()
            .create()
            .map_err(|e| IpcError::Setup {
                what: format!("create the publisher of {}", src.leaf()),
                detail: format!("{e:?}"),
            })?;
        Ok(Self {
            publisher,
            service,
            _node: node,
            block: Box::new(ScopeBlock {
                protocol: SCOPE_PROTOCOL,
                source: src as u32,
                count: 0,
                len: 0,
                run_id: crate::shared::clock::now_ns(),
                period_ns,
                axis_count,
                block: 0,
                ring_dropped: 0,
                bytes: [0; SCOPE_BLOCK_BYTES],
            }),
        })
    }

    /// Publishes `records` (split into blocks that fit); errors are dropped: the scope is a
    /// viewer, the log is the record.
    fn publish<T: Serialize>(&mut self, records: &[T]) {
        if self.service.dynamic_config().number_of_subscribers() == 0 {
            // nobody watches: no encoding, no 32 kB copy in the loop's slack
            return;
        }
        let mut rest = records;
        while !rest.is_empty() {
            let mut n = rest.len();
            let used = loop {
                match encode_records(&rest[..n], &mut self.block.bytes) {
                    Some(used) => break Some(used),
                    None if n > 1 => n /= 2,
                    None => break None,
                }
            };
            let Some(used) = used else { return };
            self.block.count = n as u32;
            self.block.len = used as u32;
            if let Ok(sample) = self.publisher.loan_uninit() {
                let _ = sample.write_payload(*self.block).send();
            }
            self.block.block = self.block.block.wrapping_add(1);
            rest = &rest[n..];
        }
    }
}

/// A tap for a recorder of `src` records of `instance`: publishes each written block on the
/// instance's scope service. When the service cannot be opened the loop runs without a scope
/// feed and says so once on stderr.
pub fn scope_tap<T: Serialize + 'static>(
    instance: &str,
    src: ScopeSource,
    period_s: f64,
    axis_count: usize,
) -> TapFactory<T> {
    let instance = instance.to_string();
    let period_ns = (period_s * 1e9).round() as u64;
    Box::new(move || -> Option<Tap<T>> {
        match ScopePublisher::open(&instance, src, period_ns, axis_count as u32) {
            Ok(mut p) => Some(Box::new(move |records: &[T], dropped: u64| {
                p.block.ring_dropped = dropped;
                p.publish(records)
            })),
            Err(e) => {
                eprintln!("feedloop: no scope feed for instance `{instance}`: {e}");
                None
            }
        }
    })
}

/// Records of one received block.
#[derive(Debug, Clone)]
pub enum ScopeRecords {
    /// From the plant.
    Plant(Vec<PlantRecord>),
    /// From the scheduler.
    Scheduler(Vec<SchedRecord>),
}

/// A received block: its header and its records.
#[derive(Debug, Clone)]
pub struct ReceivedBlock {
    /// The run it belongs to ([`ScopeBlock::run_id`]).
    pub run_id: u64,
    /// Control period, s.
    pub period_s: f64,
    /// Axes in the job.
    pub axis_count: usize,
    /// Records the recorder's ring dropped so far.
    pub ring_dropped: u64,
    /// The block's number in its run ([`ScopeBlock::block`]).
    pub block: u32,
    /// The records.
    pub records: ScopeRecords,
}

/// The viewing side: one subscriber on each of the instance's two scope services.
pub struct ScopeSubscriber {
    plant: Subscriber<ipc::Service, ScopeBlock, ()>,
    scheduler: Subscriber<ipc::Service, ScopeBlock, ()>,
    plant_service: BlockFactory,
    scheduler_service: BlockFactory,
    _node: Node<ipc::Service>,
}

fn decode<T: DeserializeOwned>(b: &ScopeBlock) -> Option<Vec<T>> {
    let n = (b.len as usize).min(SCOPE_BLOCK_BYTES);
    decode_records(&b.bytes[..n])
}

impl ScopeSubscriber {
    /// Subscribes to the scope services of `instance` (opening them when no loop runs yet: the
    /// loop's recorders find them when it starts).
    pub fn open(instance: &str) -> Result<Self, IpcError> {
        let node = create_node(instance, &format!("scope-{}", std::process::id()))?;
        let plant_service = service(&node, instance, ScopeSource::Plant)?;
        let scheduler_service = service(&node, instance, ScopeSource::Scheduler)?;
        let sub = |s: &BlockFactory, what: &str| {
            s.subscriber_builder()
                .buffer_size(SUBSCRIBER_BLOCKS)
                .create()
                .map_err(|e| IpcError::Setup {
                    what: format!(
                        "subscribe to the {what} scope feed (are two scopes watching instance \
                         `{instance}` already?)"
                    ),
                    detail: format!("{e:?}"),
                })
        };
        Ok(Self {
            plant: sub(&plant_service, "plant")?,
            scheduler: sub(&scheduler_service, "scheduler")?,
            plant_service,
            scheduler_service,
            _node: node,
        })
    }

    /// Whether both processes of the loop publish (a loop is running).
    pub fn loop_running(&self) -> (bool, bool) {
        (
            self.plant_service.dynamic_config().number_of_publishers() > 0,
            self.scheduler_service
                .dynamic_config()
                .number_of_publishers()
                > 0,
        )
    }

    /// The next queued block of either process, if any (plant first). A block of another
    /// layout version or that does not decode is skipped and counted in `bad`.
    pub fn receive(&self, bad: &mut u64) -> Result<Option<ReceivedBlock>, IpcError> {
        for (sub, src) in [
            (&self.plant, ScopeSource::Plant),
            (&self.scheduler, ScopeSource::Scheduler),
        ] {
            loop {
                let Some(s) = sub
                    .receive()
                    .map_err(|e| IpcError::Receive(format!("{e:?}")))?
                else {
                    break;
                };
                let b = s.payload();
                let records = if b.protocol != SCOPE_PROTOCOL {
                    None
                } else {
                    match src {
                        ScopeSource::Plant => decode(b).map(ScopeRecords::Plant),
                        ScopeSource::Scheduler => decode(b).map(ScopeRecords::Scheduler),
                    }
                };
                match records {
                    Some(records) => {
                        return Ok(Some(ReceivedBlock {
                            run_id: b.run_id,
                            period_s: b.period_ns as f64 * 1e-9,
                            axis_count: b.axis_count as usize,
                            ring_dropped: b.ring_dropped,
                            block: b.block,
                            records,
                        }))
                    }
                    None => *bad += 1,
                }
            }
        }
        Ok(None)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_written_block_reaches_a_subscriber_with_every_record_in_order() {
        let instance = format!("scopetest{}", std::process::id());
        let sub = ScopeSubscriber::open(&instance).unwrap();
        assert_eq!(sub.loop_running(), (false, false));
        let mut tap = scope_tap::<PlantRecord>(&instance, ScopeSource::Plant, 1e-4, 2)().unwrap();
        assert_eq!(sub.loop_running(), (true, false));
        let recs: Vec<PlantRecord> = (0..200u64)
            .map(|i| PlantRecord {
                seq: i,
                latency_ns: 1000 + i,
                ..Default::default()
            })
            .collect();
        // More than one block's bytes: split, nothing lost.
        tap(&recs[..100], 0);
        tap(&recs[100..], 0);
        let mut got = Vec::new();
        let mut bad = 0;
        while let Some(b) = sub.receive(&mut bad).unwrap() {
            assert!((b.period_s - 1e-4).abs() < 1e-12);
            assert_eq!(b.axis_count, 2);
            match b.records {
                ScopeRecords::Plant(r) => got.extend(r),
                ScopeRecords::Scheduler(_) => panic!("a plant block read as the scheduler's"),
            }
        }
        assert_eq!(bad, 0);
        assert_eq!(got, recs);
    }

    #[test]
    fn a_subscriber_that_does_not_read_loses_the_oldest_blocks_and_the_publisher_never_waits() {
        let instance = format!("scopelag{}", std::process::id());
        let sub = ScopeSubscriber::open(&instance).unwrap();
        let mut tap =
            scope_tap::<SchedRecord>(&instance, ScopeSource::Scheduler, 1e-3, 1)().unwrap();
        let n = SUBSCRIBER_BLOCKS as u64 + 50;
        for i in 0..n {
            tap(
                &[SchedRecord {
                    seq: i,
                    ..Default::default()
                }],
                0,
            );
        }
        let mut seqs = Vec::new();
        let mut bad = 0;
        while let Some(b) = sub.receive(&mut bad).unwrap() {
            if let ScopeRecords::Scheduler(r) = b.records {
                seqs.extend(r.iter().map(|r| r.seq));
            }
        }
        assert_eq!(seqs.len(), SUBSCRIBER_BLOCKS);
        assert_eq!(*seqs.last().unwrap(), n - 1, "the newest block is kept");
        assert!(seqs.windows(2).all(|w| w[1] == w[0] + 1));
    }
}
