//! SIGINT/SIGTERM turn into a stop request the loops poll (no work in the handler itself).
//! SIGUSR2 too, and it also says the launcher is gone: `feedloop run` asks the kernel to send it
//! to its children when it dies ([`die_with_parent`]). SIGHUP keeps its inherited disposition
//! (`nohup feedloop run` survives a logout).

use std::sync::atomic::{AtomicBool, Ordering};

/// Set when SIGINT, SIGTERM or the parent-death signal arrived.
pub static STOP: AtomicBool = AtomicBool::new(false);

/// Set when the parent-death signal arrived: the launcher died.
pub static PARENT_DIED: AtomicBool = AtomicBool::new(false);

/// The signal `feedloop run`'s children get when it dies (one nobody else sends them).
const PARENT_DEATH_SIGNAL: libc::c_int = libc::SIGUSR2;

extern "C" fn on_signal(sig: libc::c_int) {
    if sig == PARENT_DEATH_SIGNAL {
        PARENT_DIED.store(true, Ordering::SeqCst);
    }
    STOP.store(true, Ordering::SeqCst);
}

/// Installs the handlers.
pub fn install() {
    let handler = on_signal as extern "C" fn(libc::c_int) as libc::sighandler_t;
    // SAFETY: the handler only stores to atomics, which is async-signal-safe.
    unsafe {
        libc::signal(libc::SIGINT, handler);
        libc::signal(libc::SIGTERM, handler);
        libc::signal(PARENT_DEATH_SIGNAL, handler);
    }
}

/// Writes to a closed pipe end the process quietly, as for other command-line tools (`feedloop
/// sim ... | head -1`), instead of a panic in `println!`.
pub fn quiet_broken_pipe() {
    // SAFETY: restoring the default disposition of SIGPIPE.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
}

/// Makes a child about to be started get the parent-death signal when this process dies, however it dies
/// (`kill -9` included): the child then stops its loop safely on its own.
pub fn die_with_parent(cmd: &mut std::process::Command) {
    use std::os::unix::process::CommandExt;
    // SAFETY: `getpid` here, and `prctl`, `getppid` and `_exit` in the forked child, are
    // async-signal-safe and touch no memory of the parent.
    let parent = unsafe { libc::getpid() };
    unsafe {
        cmd.pre_exec(move || {
            if libc::prctl(libc::PR_SET_PDEATHSIG, PARENT_DEATH_SIGNAL) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            // The parent may have died before the request: then nobody would send the signal.
            if libc::getppid() != parent {
                libc::_exit(1);
            }
            Ok(())
        });
    }
}
