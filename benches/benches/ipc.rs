//! Cross-process round trip of the real wire types (a `SensorSample` out, an `ActuatorCommand`
//! back), four transports compared in one run:
//! - iceoryx2 publish-subscribe, busy-polling (what the loop uses with `--wait busy`);
//! - iceoryx2 publish-subscribe + event, blocking wait (`--wait block`);
//! - a Unix domain socket carrying bincode frames (ordinary IPC);
//! - a raw shared-memory cache line with atomics (the practical floor).
//!
//! The echo peer is this same bench binary, re-executed with `FEEDLOOP_BENCH_PEER` set. The bench
//! pins itself to CPU 0 and the peer to CPU 1, so every transport is measured across cores (the
//! case the loop runs in); `FEEDLOOP_BENCH_CPUS=a,b` picks other CPUs (`a,a` for one core).
//! `cargo bench -p feedloop-benches --bench ipc`

use std::io::{Read, Write};
use std::os::unix::net::{UnixListener, UnixStream};
use std::process::{Child, Command};
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use criterion::Criterion;
use feedloop_model::job::WaitKind;
use feedloop_runtime::shared::clock::now_ns;
use feedloop_runtime::shared::ipc::{plant_endpoint, scheduler_endpoint, WaitOutcome};
use feedloop_runtime::shared::rt;
use feedloop_runtime::shared::wire::{ActuatorCommand, SensorSample, FLAG_END};

const PEER_ENV: &str = "FEEDLOOP_BENCH_PEER";
const CPUS_ENV: &str = "FEEDLOOP_BENCH_CPUS";

/// The CPUs of the bench (index 0) and of the echo peer (index 1).
fn cpus() -> [usize; 2] {
    let spec = std::env::var(CPUS_ENV).unwrap_or_else(|_| "0,1".into());
    let v: Vec<usize> = spec
        .split(',')
        .map(|c| {
            c.trim()
                .parse()
                .expect("FEEDLOOP_BENCH_CPUS: two CPU numbers, e.g. 0,1")
        })
        .collect();
    assert_eq!(v.len(), 2, "FEEDLOOP_BENCH_CPUS: two CPU numbers, e.g. 0,1");
    [v[0], v[1]]
}

fn pin(cpu: usize) {
    let applied = rt::apply(&rt::RtRequest {
        cpu: Some(cpu),
        ..Default::default()
    });
    if !applied.notes.is_empty() {
        eprintln!("not pinned: {}", applied.notes.join("; "));
    }
}

fn spawn_peer(spec: &str) -> Child {
    Command::new(std::env::current_exe().expect("bench exe"))
        .env(PEER_ENV, spec)
        .spawn()
        .expect("spawning the echo peer")
}

fn answer(s: &SensorSample) -> ActuatorCommand {
    let mut c = ActuatorCommand::empty(s.axis_count, s.instance_tag);
    c.seq = s.seq;
    c.axes[0].torque = s.axes[0].motor_vel * -2.0;
    c
}

fn sample(seq: u64) -> SensorSample {
    let mut s = SensorSample::empty(2, 7);
    s.seq = seq;
    s.axes[0].motor_vel = seq as f64;
    s
}

// ---------------------------------------------------------------- iceoryx2
fn iox_peer(instance: &str, wait: WaitKind) {
    let ep = scheduler_endpoint(instance, wait, Duration::ZERO).expect("peer endpoint");
    loop {
        match ep
            .receive_until(now_ns() + 10_000_000_000)
            .expect("receive")
        {
            WaitOutcome::Got(s) => {
                if s.flags & FLAG_END != 0 {
                    return;
                }
                ep.send(answer(&s)).expect("send");
            }
            WaitOutcome::TimedOut => return,
        }
    }
}

/// Benchmarks `round_trip`, given the sequence number of each trip (1, 2, ...), as `name`.
fn bench_round_trips(c: &mut Criterion, name: &str, mut round_trip: impl FnMut(u64)) {
    let mut k = 0u64;
    c.bench_function(name, |b| {
        b.iter_custom(|iters| {
            let t = Instant::now();
            for _ in 0..iters {
                k += 1;
                round_trip(k);
            }
            t.elapsed()
        })
    });
}

fn bench_iox(c: &mut Criterion, name: &str, wait: WaitKind) {
    let instance = format!("bench-{}-{}", wait.id(), std::process::id());
    let ep = plant_endpoint(&instance, wait, Duration::ZERO).expect("endpoint");
    let mut child = spawn_peer(&format!("iox-{}:{instance}", wait.id()));
    // Handshake: connections are lazy, so probe until an answer comes back.
    let start = Instant::now();
    let mut seq = 1u64 << 40;
    loop {
        if ep.peer_connected() {
            ep.send(sample(seq)).expect("probe");
            if let WaitOutcome::Got(_) = ep
                .receive_until(now_ns() + 20_000_000)
                .expect("probe reply")
            {
                break;
            }
        }
        assert!(
            start.elapsed() < Duration::from_secs(10),
            "echo peer did not connect"
        );
        std::thread::sleep(Duration::from_millis(5));
        seq += 1;
    }
    std::thread::sleep(Duration::from_millis(20));
    ep.drain().expect("drain");
    bench_round_trips(c, name, |k| {
        ep.send(sample(k)).expect("send");
        loop {
            match ep.receive_until(now_ns() + 1_000_000_000).expect("receive") {
                WaitOutcome::Got(r) if r.seq == k => break,
                WaitOutcome::Got(_) => continue,
                WaitOutcome::TimedOut => panic!("echo peer went silent"),
            }
        }
    });
    let mut end = sample(u64::MAX);
    end.flags = FLAG_END;
    let _ = ep.send(end);
    let _ = child.wait();
}

// ---------------------------------------------------------------- Unix socket + bincode
fn cfg() -> impl bincode::config::Config {
    bincode::config::standard().with_fixed_int_encoding()
}

fn write_frame(s: &mut UnixStream, buf: &mut Vec<u8>, v: &impl serde::Serialize) {
    buf.clear();
    buf.extend_from_slice(&[0; 4]);
    bincode::serde::encode_into_std_write(v, buf, cfg()).expect("encode");
    let n = (buf.len() - 4) as u32;
    buf[..4].copy_from_slice(&n.to_le_bytes());
    s.write_all(buf).expect("write");
}

fn read_frame<T: serde::de::DeserializeOwned>(s: &mut UnixStream, buf: &mut Vec<u8>) -> Option<T> {
    let mut len = [0u8; 4];
    s.read_exact(&mut len).ok()?;
    buf.resize(u32::from_le_bytes(len) as usize, 0);
    s.read_exact(buf).ok()?;
    bincode::serde::decode_from_slice(buf, cfg())
        .ok()
        .map(|(v, _)| v)
}

fn uds_peer(path: &str) {
    let mut s = UnixStream::connect(path).expect("connect");
    let (mut rb, mut wb) = (Vec::new(), Vec::new());
    while let Some(x) = read_frame::<SensorSample>(&mut s, &mut rb) {
        if x.flags & FLAG_END != 0 {
            return;
        }
        write_frame(&mut s, &mut wb, &answer(&x));
    }
}

fn bench_uds(c: &mut Criterion) {
    let path = std::env::temp_dir().join(format!("feedloop-bench-{}.sock", std::process::id()));
    let _ = std::fs::remove_file(&path);
    let listener = UnixListener::bind(&path).expect("bind");
    let mut child = spawn_peer(&format!("uds:{}", path.display()));
    let (mut s, _) = listener.accept().expect("accept");
    let (mut rb, mut wb) = (Vec::new(), Vec::new());
    bench_round_trips(c, "unix socket + bincode", |k| {
        write_frame(&mut s, &mut wb, &sample(k));
        let r: ActuatorCommand = read_frame(&mut s, &mut rb).expect("reply");
        assert_eq!(r.seq, k);
    });
    let mut end = sample(0);
    end.flags = FLAG_END;
    write_frame(&mut s, &mut wb, &end);
    let _ = child.wait();
    let _ = std::fs::remove_file(&path);
}

// ---------------------------------------------------------------- raw shared memory
const PING: usize = 0;
const SAMPLE_AT: usize = 64;
const PONG: usize = 2048;
const CMD_AT: usize = 2112;
const SHM_BYTES: usize = 4096;

struct Shm {
    ptr: *mut u8,
}

impl Shm {
    fn open(path: &str, create: bool) -> Shm {
        let c = std::ffi::CString::new(path).expect("path");
        // SAFETY: plain POSIX calls on a file we own; the mapping outlives every access.
        unsafe {
            let flags = if create {
                libc::O_RDWR | libc::O_CREAT
            } else {
                libc::O_RDWR
            };
            let fd = libc::open(c.as_ptr(), flags, 0o600);
            assert!(fd >= 0, "open {path}");
            if create {
                assert_eq!(libc::ftruncate(fd, SHM_BYTES as libc::off_t), 0);
            }
            let p = libc::mmap(
                std::ptr::null_mut(),
                SHM_BYTES,
                libc::PROT_READ | libc::PROT_WRITE,
                libc::MAP_SHARED,
                fd,
                0,
            );
            assert_ne!(p, libc::MAP_FAILED);
            libc::close(fd);
            Shm { ptr: p as *mut u8 }
        }
    }
    fn seq(&self, at: usize) -> &AtomicU64 {
        // SAFETY: 8-aligned offsets inside the mapping; AtomicU64 has the layout of u64.
        unsafe { &*(self.ptr.add(at) as *const AtomicU64) }
    }
    fn write<T: Copy>(&self, at: usize, v: &T) {
        // SAFETY: in-bounds, the peer reads only after the release store that follows.
        unsafe { std::ptr::write_volatile(self.ptr.add(at) as *mut T, *v) }
    }
    fn read<T: Copy>(&self, at: usize) -> T {
        // SAFETY: as above, after the acquire load of the sequence.
        unsafe { std::ptr::read_volatile(self.ptr.add(at) as *const T) }
    }
}

fn shm_peer(path: &str) {
    let shm = Shm::open(path, false);
    let mut last = 0u64;
    loop {
        let k = shm.seq(PING).load(Ordering::Acquire);
        if k == u64::MAX {
            return;
        }
        if k != last {
            let s: SensorSample = shm.read(SAMPLE_AT);
            shm.write(CMD_AT, &answer(&s));
            shm.seq(PONG).store(k, Ordering::Release);
            last = k;
        } else {
            std::hint::spin_loop();
        }
    }
}

fn bench_shm(c: &mut Criterion) {
    let path = format!("/dev/shm/feedloop-bench-{}", std::process::id());
    let shm = Shm::open(&path, true);
    shm.seq(PING).store(0, Ordering::Release);
    shm.seq(PONG).store(0, Ordering::Release);
    let mut child = spawn_peer(&format!("shm:{path}"));
    bench_round_trips(c, "raw shared memory + atomics (floor)", |k| {
        shm.write(SAMPLE_AT, &sample(k));
        shm.seq(PING).store(k, Ordering::Release);
        while shm.seq(PONG).load(Ordering::Acquire) != k {
            std::hint::spin_loop();
        }
        let r: ActuatorCommand = shm.read(CMD_AT);
        assert_eq!(r.seq, k);
    });
    shm.seq(PING).store(u64::MAX, Ordering::Release);
    let _ = child.wait();
    let _ = std::fs::remove_file(&path);
}

fn main() {
    if let Ok(spec) = std::env::var(PEER_ENV) {
        pin(cpus()[1]);
        let (kind, arg) = spec.split_once(':').expect("peer spec kind:arg");
        match kind {
            "iox-busy" => iox_peer(arg, WaitKind::Busy),
            "iox-block" => iox_peer(arg, WaitKind::Block),
            "uds" => uds_peer(arg),
            "shm" => shm_peer(arg),
            other => panic!("unknown peer kind {other}"),
        }
        return;
    }
    pin(cpus()[0]);
    let mut c = Criterion::default()
        .measurement_time(Duration::from_secs(3))
        .warm_up_time(Duration::from_secs(1))
        .configure_from_args();
    bench_shm(&mut c);
    bench_iox(&mut c, "iceoryx2 busy-poll", WaitKind::Busy);
    bench_iox(&mut c, "iceoryx2 blocking wait (event)", WaitKind::Block);
    bench_uds(&mut c);
    c.final_summary();
}
