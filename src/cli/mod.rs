//! The command line's subcommands, one file each (`Args` + `run`): [`calibrate`],
//! [`survey`], [`detect`], [`simulate`], [`decode`], [`daemon`], [`query`], [`overlay`].
//! Helpers several of them share: [`io`] (reading images and clouds, writing results),
//! [`rig`] (a rig's `NAME=PATH` inputs), [`progress`] and [`summary`] (what is printed).

/// `println!` on stdout that tolerates a closed stdout (`roomcal … | head`): the rest of
/// the output is dropped, the command's work, files and exit status are unchanged (Rust
/// ignores SIGPIPE, so `println!` would panic on the broken pipe).
macro_rules! say {
    ($($arg:tt)*) => {{
        use std::io::Write as _;
        let _ = writeln!(std::io::stdout(), $($arg)*);
    }};
}

/// [`say!`] without the newline.
macro_rules! say_raw {
    ($($arg:tt)*) => {{
        use std::io::Write as _;
        let _ = write!(std::io::stdout(), $($arg)*);
    }};
}

pub mod calibrate;
#[cfg(feature = "daemon")]
pub mod daemon;
pub mod decode;
pub mod detect;
pub mod io;
pub mod overlay;
pub mod progress;
pub mod query;
pub mod rig;
pub mod simulate;
pub mod summary;
pub mod survey;

/// An error with the exit code it maps to; `error: None` when the output already said it.
pub struct Failure {
    pub code: u8,
    pub error: Option<anyhow::Error>,
}

impl Failure {
    pub fn new(code: u8, error: impl Into<anyhow::Error>) -> Failure {
        Failure { code, error: Some(error.into()) }
    }
}

/// Bad input (exit 2): the message names the file and the problem.
pub fn bad_input(error: impl Into<anyhow::Error>) -> Failure {
    Failure::new(2, error)
}

/// Rejected by the quality gate (exit 3): the status line (or the JSON's status and
/// reason) has said why.
pub fn rejected() -> Failure {
    Failure { code: 3, error: None }
}
