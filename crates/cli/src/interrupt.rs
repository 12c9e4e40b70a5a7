//! Ctrl-C as a request to finish: after [`install`], the first SIGINT (or SIGTERM) only sets a
//! flag that a long loop polls with [`requested`], so that it can stop and still write its
//! outputs; the handler then steps aside, and a second Ctrl-C ends the process at once.

use std::sync::atomic::{AtomicBool, Ordering};

static REQUESTED: AtomicBool = AtomicBool::new(false);

/// Whether Ctrl-C was pressed since [`install`].
pub fn requested() -> bool {
    REQUESTED.load(Ordering::SeqCst)
}

#[cfg(unix)]
extern "C" fn on_signal(_: libc::c_int) {
    // Only an atomic store: async-signal-safe. SA_RESETHAND has restored the default action.
    REQUESTED.store(true, Ordering::SeqCst);
}

/// Installs the handler for SIGINT and SIGTERM (once is enough; again is harmless). Returns
/// whether it is in place (elsewhere than Unix Ctrl-C ends the process as usual).
pub fn install() -> bool {
    #[cfg(unix)]
    {
        let mut ok = true;
        for signal in [libc::SIGINT, libc::SIGTERM] {
            // SAFETY: a zeroed sigaction is valid; the handler only stores an atomic.
            unsafe {
                let mut action: libc::sigaction = std::mem::zeroed();
                action.sa_sigaction = on_signal as extern "C" fn(libc::c_int) as libc::sighandler_t;
                action.sa_flags = libc::SA_RESETHAND | libc::SA_RESTART;
                libc::sigemptyset(&mut action.sa_mask);
                ok &= libc::sigaction(signal, &action, std::ptr::null_mut()) == 0;
            }
        }
        ok
    }
    #[cfg(not(unix))]
    {
        false
    }
}

/// Gives SIGINT and SIGTERM back their default action (ending the process), for a command that
/// waits after its work is done (a viewer serving until Ctrl-C).
pub fn restore_default() {
    #[cfg(unix)]
    for signal in [libc::SIGINT, libc::SIGTERM] {
        // SAFETY: setting the default disposition.
        unsafe { libc::signal(signal, libc::SIG_DFL) };
    }
}
