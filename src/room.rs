//! Reading room files (TOML) with errors that name the file, the key and the problem.

use std::path::{Path, PathBuf};

use crate::target::{Room, RoomError};

/// Why a room file could not be used.
#[derive(Debug, thiserror::Error)]
pub enum RoomFileError {
    #[error("room file {path}: cannot read: {source}")]
    Read { path: PathBuf, source: std::io::Error },
    /// Syntax errors, unknown keys, missing fields and wrong types (toml names the key and line).
    #[error("room file {path}: {message}")]
    Parse { path: PathBuf, message: String },
    #[error("room file {path}: {source}")]
    Invalid { path: PathBuf, source: RoomError },
}

impl std::error::Error for RoomError {}

/// Reads and validates a room file.
pub fn load(path: &Path) -> Result<Room, RoomFileError> {
    let text = std::fs::read_to_string(path)
        .map_err(|source| RoomFileError::Read { path: path.to_owned(), source })?;
    parse(&text, path)
}

/// Parses and validates room-file text; `path` only names the source in errors.
pub fn parse(text: &str, path: &Path) -> Result<Room, RoomFileError> {
    let room: Room = toml::from_str(text).map_err(|e| RoomFileError::Parse {
        path: path.to_owned(),
        message: toml_message(text, &e),
    })?;
    room.validate().map_err(|source| RoomFileError::Invalid { path: path.to_owned(), source })?;
    Ok(room)
}

/// Most characters of a TOML file's line, or of the parser's message, that an error echoes:
/// a 50 MB value is named, not printed.
const ECHO_CHARS: usize = 120;

/// A TOML parse error of `text` as toml words it (the line, a caret under the problem, the
/// message), indented under the file's name, with the line and the message cut to
/// [`ECHO_CHARS`] characters around the problem: a huge bad value costs neither memory nor
/// a screenful. Shared by the room, rig and daemon configuration files.
pub fn toml_message(text: &str, e: &toml::de::Error) -> String {
    let message = clip(e.message().trim_end(), 0, ECHO_CHARS);
    let Some(span) = e.span() else {
        return message;
    };
    let mut start = span.start.min(text.len());
    while !text.is_char_boundary(start) {
        start -= 1;
    }
    let line_start = text[..start].rfind('\n').map_or(0, |i| i + 1);
    let line_end = text[start..].find('\n').map_or(text.len(), |i| start + i);
    let line_no = text[..line_start].matches('\n').count() + 1;
    let line = text[line_start..line_end].trim_end_matches('\r');
    let column = text[line_start..start].chars().count();
    // A long line is shown as its start (its key) and the part around the problem.
    let head = ECHO_CHARS / 4;
    let (excerpt, caret_at) = if column < ECHO_CHARS - head {
        (clip(line, 0, ECHO_CHARS), column)
    } else {
        let skip = column - head;
        let excerpt = clip(line, 0, head) + &clip(line, skip, ECHO_CHARS - head);
        (excerpt, head + 1 + column - skip)
    };
    let gutter = " ".repeat(line_no.to_string().len());
    format!(
        "TOML parse error at line {line_no}, column {}\n  {gutter} |\n  {line_no} | {excerpt}\n  \
         {gutter} | {}^\n  {message}",
        column + 1,
        " ".repeat(caret_at),
    )
}

/// `chars` characters of `s` from character `skip`, with `…` where it goes on.
fn clip(s: &str, skip: usize, chars: usize) -> String {
    let mut out = String::new();
    let mut rest = s.chars().skip(skip);
    out.extend(rest.by_ref().take(chars));
    if rest.next().is_some() {
        out.push('…');
    }
    out
}

/// What the room file says of `survey.covariance` above it (`target::SurveySpec::covariance`
/// has the whole definition; DESIGN.md's `[survey]` does not hold the key).
const COVARIANCE_COMMENT: &str =
    "# the joint covariance, lower triangle by rows: every board's [δω δt] \
(rad, m; room frame) in [[survey.boards]] order,\n# then every plane's [δω δd] (the normal's turn, \
rad; the offset at the origin, m) in [[survey.planes]] order; the boards' mean frame as the σ\n";

/// The room file as TOML (for fixtures and the simulator's output). A survey's covariance
/// is written one row per line, right under `[survey]`: the pretty writer's one number per
/// line would make it most of the file.
pub fn to_toml(room: &Room) -> String {
    let Some(covariance) = room.survey.as_ref().map(|s| &s.covariance).filter(|c| !c.is_empty())
    else {
        return toml::to_string_pretty(room).expect("a room always serialises to TOML");
    };
    let mut bare = room.clone();
    if let Some(survey) = bare.survey.as_mut() {
        survey.covariance.clear();
    }
    let text = toml::to_string_pretty(&bare).expect("a room always serialises to TOML");
    let rows: Vec<String> = covariance
        .iter()
        .map(|row| {
            let numbers: Vec<String> = row.iter().map(|x| format!("{x:e}")).collect();
            format!("    [{}],", numbers.join(", "))
        })
        .collect();
    let table = format!("[survey]\n{COVARIANCE_COMMENT}covariance = [\n{}\n]\n", rows.join("\n"));
    text.replacen("[survey]\n", &table, 1)
}
