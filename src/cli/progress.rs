//! Progress of a long command on a terminal: one plain line on stderr, rewritten in place
//! (`[3/9] calibrate: detecting boards, frame 2`), cleared when the work ends. Nothing at all
//! is written when stderr is not a terminal (a log, a pipe, a test) or the user asked for
//! quiet, so scripts see exactly the output they saw before.
//!
//! The API is the whole of it: [`Progress::on_stderr`] with the number of steps, then
//! [`Progress::step`] as each step starts, [`Progress::note`] for a message that must stay,
//! and the line clears itself when the `Progress` is dropped (also on an early `?` return,
//! so an error message starts on a clean line).

use std::io::{IsTerminal, Write};

/// The longest line drawn, in characters: a line wider than the terminal wraps, and `\r`
/// would then redraw only its last row. 79 fits the narrowest usual terminal; the terminal's
/// real width is not asked for (that would need a new dependency).
pub const MAX_WIDTH: usize = 79;

/// A progress line on a writer; `W` is stderr except in tests.
pub struct Progress<W: Write = std::io::Stderr> {
    /// `None` when progress is not shown: every call is then a no-op.
    out: Option<W>,
    label: String,
    total: usize,
    done: usize,
    /// The line last drawn, redrawn under a note.
    line: String,
    /// Characters on screen, to blank them when a shorter line replaces them.
    shown: usize,
}

impl Progress {
    /// Progress of `total` steps of `label` (the command) on stderr, shown only when stderr
    /// is a terminal and `quiet` is false.
    pub fn on_stderr(label: &str, total: usize, quiet: bool) -> Progress {
        let stderr = std::io::stderr();
        let shown = !quiet && stderr.is_terminal();
        Progress::new(shown.then_some(stderr), label, total)
    }
}

impl<W: Write> Progress<W> {
    /// Progress on `out`, or shown nowhere when `out` is `None`.
    pub fn new(out: Option<W>, label: &str, total: usize) -> Progress<W> {
        Progress { out, label: label.to_string(), total, done: 0, line: String::new(), shown: 0 }
    }

    /// Step `what` starts: the line shows it with its number.
    pub fn step(&mut self, what: &str) {
        self.done += 1;
        // More steps than announced (a count that was an estimate) raises the total rather
        // than print `[10/9]`.
        self.total = self.total.max(self.done);
        self.line = render(&self.label, self.done, self.total, what);
        self.draw();
    }

    /// A message that stays (a warning): printed on its own line, the progress line redrawn
    /// under it. Printed even when progress is not shown: only the line is optional.
    pub fn note(&mut self, message: &str) {
        let Some(out) = self.out.as_mut() else {
            eprintln!("{message}");
            return;
        };
        let _ = write!(out, "\r{:width$}\r{message}\n", "", width = self.shown);
        self.shown = 0;
        self.draw();
    }

    /// The writer, once the line is cleared (tests read what was drawn).
    pub fn finish(mut self) -> Option<W> {
        self.clear();
        self.out.take()
    }

    fn draw(&mut self) {
        let (Some(out), line) = (self.out.as_mut(), &self.line) else { return };
        if line.is_empty() {
            return;
        }
        let width = line.chars().count();
        // Blank what a longer previous line leaves behind, then park the cursor after the text.
        let pad = self.shown.saturating_sub(width);
        let _ = write!(out, "\r{line}{:pad$}", "");
        if pad > 0 {
            let _ = write!(out, "\r{line}");
        }
        let _ = out.flush();
        self.shown = width;
    }

    fn clear(&mut self) {
        let Some(out) = self.out.as_mut() else { return };
        if self.shown > 0 {
            let _ = write!(out, "\r{:width$}\r", "", width = self.shown);
            let _ = out.flush();
        }
        self.shown = 0;
    }
}

impl<W: Write> Drop for Progress<W> {
    fn drop(&mut self) {
        self.clear();
    }
}

/// The progress line: `[done/total] label: what`, cut to [`MAX_WIDTH`] characters with `…`
/// (the step's name is what is cut: a long file name must not hide the count).
pub fn render(label: &str, done: usize, total: usize, what: &str) -> String {
    let line = match what {
        "" => format!("[{done}/{total}] {label}"),
        _ => format!("[{done}/{total}] {label}: {what}"),
    };
    if line.chars().count() <= MAX_WIDTH {
        return line;
    }
    let mut cut: String = line.chars().take(MAX_WIDTH - 1).collect();
    cut.push('…');
    cut
}

#[cfg(test)]
mod tests {
    use super::*;

    fn drawn(progress: Progress<Vec<u8>>) -> String {
        String::from_utf8(progress.finish().unwrap()).unwrap()
    }

    #[test]
    fn a_line_counts_its_steps() {
        assert_eq!(
            render("calibrate", 2, 5, "reading image.png"),
            "[2/5] calibrate: reading image.png"
        );
        assert_eq!(render("survey", 1, 3, ""), "[1/3] survey");
    }

    #[test]
    fn a_long_step_is_cut_to_the_width_keeping_the_count() {
        let name = "x".repeat(200);
        let line = render("calibrate", 12, 40, &name);
        assert_eq!(line.chars().count(), MAX_WIDTH);
        assert!(line.starts_with("[12/40] calibrate: xxx"), "{line}");
        assert!(line.ends_with("x…"), "{line}");
    }

    #[test]
    fn each_step_rewrites_the_line_and_the_end_clears_it() {
        let mut progress = Progress::new(Some(Vec::new()), "calibrate", 2);
        progress.step("reading a-long-name.png");
        progress.step("solving");
        // The second line is shorter: the rest of the first is blanked, the cursor parked
        // after the text; the end blanks the line and returns to its start.
        let first = "[1/2] calibrate: reading a-long-name.png";
        let second = "[2/2] calibrate: solving";
        let pad = " ".repeat(first.len() - second.len());
        let blank = " ".repeat(second.len());
        assert_eq!(drawn(progress), format!("\r{first}\r{second}{pad}\r{second}\r{blank}\r"));
    }

    #[test]
    fn a_note_stays_above_the_line() {
        let mut progress = Progress::new(Some(Vec::new()), "detect", 1);
        progress.step("cloud");
        progress.note("cloud.pcd: a plane; not used as a board");
        let line = "[1/1] detect: cloud";
        let blank = " ".repeat(line.len());
        assert_eq!(
            drawn(progress),
            format!(
                "\r{line}\r{blank}\rcloud.pcd: a plane; not used as a board\n\r{line}\r{blank}\r"
            )
        );
    }

    #[test]
    fn more_steps_than_announced_raise_the_total() {
        let mut progress = Progress::new(Some(Vec::new()), "survey", 1);
        progress.step("a");
        progress.step("b");
        assert!(drawn(progress).contains("[2/2] survey: b"));
    }

    #[test]
    fn progress_shown_nowhere_writes_nothing() {
        let mut progress = Progress::<Vec<u8>>::new(None, "calibrate", 3);
        progress.step("reading");
        assert!(progress.finish().is_none());
    }
}
