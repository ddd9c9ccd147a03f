//! Progress of a multi-frame `roomcal calibrate` (src/cli/progress.rs) through the binary:
//! nothing at all on stderr when it is not a terminal (a pipe, here), the updating line when
//! it is one (a pseudo-terminal from util-linux's `script`), and nothing with `--quiet`.

use std::path::Path;
use std::process::Command;

use crate::common::fixture;
use crate::common::scratch::Scratch;

/// `calibrate` on two frames of the six-board fixture (the same pair twice).
fn two_frame_args(dir: &Path, extra: &[&str]) -> Vec<String> {
    let (image, cloud) =
        (fixture("six-boards-pandar64/image.png"), fixture("six-boards-pandar64/cloud.pcd"));
    let (image, cloud) = (image.to_str().unwrap(), cloud.to_str().unwrap());
    let mut args: Vec<String> =
        ["calibrate", "--room", fixture("six-boards-pandar64/room.toml").to_str().unwrap()]
            .into_iter()
            .chain(["--image", image, "--image", image, "--cloud", cloud, "--cloud", cloud])
            .map(String::from)
            .collect();
    args.push("--out".into());
    args.push(dir.join("result.json").to_string_lossy().into_owned());
    args.extend(extra.iter().map(|s| s.to_string()));
    args
}

/// Runs the binary with stdout and stderr on a pseudo-terminal (`script -qec`); returns what
/// the terminal received, or `None` when `script` is missing.
fn on_a_terminal(args: &[String]) -> Option<String> {
    let quoted: Vec<String> = std::iter::once(crate::common::BIN.to_string())
        .chain(args.iter().cloned())
        .map(|a| format!("'{}'", a.replace('\'', r"'\''")))
        .collect();
    let out =
        Command::new("script").args(["-qec", &quoted.join(" "), "/dev/null"]).output().ok()?;
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stdout));
    Some(String::from_utf8_lossy(&out.stdout).into_owned())
}

#[test]
fn a_pipe_gets_no_progress() {
    let dir = Scratch::new("progress-pipe");
    let out = Command::new(crate::common::BIN)
        .args(two_frame_args(&dir, &[]))
        .output()
        .expect("roomcal runs");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(0), "{stderr}");
    assert!(!stderr.contains('\r') && !stderr.contains("[1/"), "progress on a pipe: {stderr:?}");
    assert!(String::from_utf8_lossy(&out.stdout).starts_with("roomcal calibrate: accepted"));
}

#[test]
fn a_terminal_sees_each_step_then_a_cleared_line() {
    let dir = Scratch::new("progress-tty");
    let Some(screen) = on_a_terminal(&two_frame_args(&dir, &[])) else {
        crate::common::skipped("util-linux `script` is not installed (no pseudo-terminal)");
        return;
    };
    // Two images, two clouds, two frames' detection, the solve, the writing.
    let steps = [
        "[1/8] calibrate: reading ",
        "[3/8] calibrate: reading ",
        "[5/8] calibrate: detecting boards, frame 1 of 2",
        "[6/8] calibrate: detecting boards, frame 2 of 2",
        "[7/8] calibrate: solving",
        "[8/8] calibrate: writing the results",
    ];
    let mut at = 0;
    for step in steps {
        let found = screen[at..].find(&format!("\r{step}"));
        assert!(found.is_some(), "`{step}` missing after byte {at}: {screen:?}");
        at += found.unwrap();
    }
    // The last line is blanked and the cursor returned before the summary starts.
    let summary = screen.find("roomcal calibrate: accepted").expect("the summary");
    assert!(screen[..summary].trim_end_matches(['\r', '\n']).ends_with(&" ".repeat(10)));
}

#[test]
fn quiet_silences_the_progress_on_a_terminal() {
    let dir = Scratch::new("progress-quiet");
    let Some(screen) = on_a_terminal(&two_frame_args(&dir, &["--quiet"])) else {
        crate::common::skipped("util-linux `script` is not installed (no pseudo-terminal)");
        return;
    };
    assert!(!screen.contains("[1/8]"), "progress despite --quiet: {screen:?}");
    assert!(screen.starts_with("roomcal calibrate: accepted"), "{screen:?}");
}
