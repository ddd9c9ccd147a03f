//! The room file's `[survey]` table (DESIGN.md, "Surveyed rooms"): parsed, validated with
//! errors naming the key and the entry, written back by `to_toml` unchanged; room files
//! without it are unchanged. Its optional joint covariance (`survey.covariance`, the lower
//! triangle by rows over 6 parameters per board and 4 per plane) likewise.

use std::path::Path;

use roomcal::room::{parse, to_toml};

const GOOD: &str = include_str!("../../config/room.toml");

/// The design's room with a survey of its six boards and two planes.
fn surveyed() -> String {
    let mut text = format!("{GOOD}\n[survey]\nvisits = 10\nframe = \"board 0, floor-levelled\"\n");
    for b in 0..6 {
        let angle: f64 = 0.3 * b as f64;
        let (c, s) = (angle.cos(), angle.sin());
        text += &format!(
            "[[survey.boards]]\nrotation = [[{c}, {}, 0.0], [{s}, {c}, 0.0], [0.0, 0.0, 1.0]]\n\
             translation = [{}, 0.25, 4.5]\nsigma_m = 0.0003\nsigma_deg = 0.005\n",
            -s,
            b as f64 * 1.5 - 3.0
        );
    }
    text += "[[survey.planes]]\nname = \"floor\"\nnormal = [0.0, 1.0, 0.0]\noffset = 2.2\nsigma_m = 0.001\nsigma_deg = 0.01\n";
    text += "[[survey.planes]]\nname = \"front wall\"\nnormal = [0.6, 0.0, 0.8]\noffset = 9.5\nsigma_m = 0.002\nsigma_deg = 0.02\n";
    text
}

fn error_of(text: &str) -> String {
    match parse(text, Path::new("bad-room.toml")) {
        Ok(_) => panic!("accepted a bad survey"),
        Err(e) => e.to_string(),
    }
}

#[test]
fn a_survey_parses_and_round_trips_through_to_toml() {
    let room = parse(&surveyed(), Path::new("room.toml")).unwrap();
    let survey = room.survey.as_ref().expect("the [survey] table is read");
    assert_eq!((survey.visits, survey.boards.len(), survey.planes.len()), (10, 6, 2));
    assert_eq!(survey.frame.as_str(), "board 0, floor-levelled");
    assert_eq!(survey.planes[1].name.as_str(), "front wall");
    assert_eq!(survey.boards[2].translation, [0.0, 0.25, 4.5]);
    let again = parse(&to_toml(&room), Path::new("again.toml")).unwrap();
    assert_eq!(again, room, "to_toml loses or changes something of the survey");
}

#[test]
fn a_room_without_a_survey_writes_no_survey() {
    let room = parse(GOOD, Path::new("room.toml")).unwrap();
    assert!(room.survey.is_none());
    assert!(!to_toml(&room).contains("survey"));
}

#[test]
fn survey_mistakes_name_the_key_and_the_entry() {
    let text = surveyed();
    let cases: [(String, &[&str]); 7] = [
        (text.replace("normal = [0.6, 0.0, 0.8]", "normal = [0.6, 0.0, 0.9]"), &["survey.planes[1].normal", "unit"]),
        (text.replacen("translation = [-3, 0.25", "translation = [nan, 0.25", 1), &["survey.boards.translation", "entry 0", "finite"]),
        (text.replacen("sigma_m = 0.0003", "sigma_m = -0.0003", 1), &["survey.boards.sigma_m", "negative"]),
        (text.replace("visits = 10", "visits = 1"), &["survey.visits", "2 visits"]),
        (text.replacen("[0.0, 0.0, 1.0]]\ntranslation = [-1.5", "[0.0, 0.0, -1.0]]\ntranslation = [-1.7", 1), &["survey.boards[1].rotation", "orthonormal"]),
        (text.replacen("[[survey.boards]]", "", 1).replacen("rotation = [[1, -0, 0.0], [0, 1, 0.0], [0.0, 0.0, 1.0]]\ntranslation = [-3, 0.25, 4.5]\nsigma_m = 0.0003\nsigma_deg = 0.005\n", "", 1), &["survey.boards", "5 entries", "6 boards"]),
        (text.replace("sigma_deg = 0.02\n", "sigma_deg = 0.02\nweight = 1\n"), &["weight"]),
    ];
    for (bad, words) in cases {
        let message = error_of(&bad);
        for w in words {
            assert!(message.contains(w), "`{w}` missing from: {message}");
        }
    }
}

/// [`surveyed`] with a covariance: `row(i)` gives row `i` (6 boards, 2 planes: 44 rows).
fn with_covariance(row: impl Fn(usize) -> String) -> String {
    let text = surveyed();
    let rows: Vec<String> = (0..44).map(row).collect();
    text.replacen(
        "frame = \"board 0, floor-levelled\"\n",
        &format!("frame = \"board 0, floor-levelled\"\ncovariance = [\n{}\n]\n", rows.join(",\n")),
        1,
    )
}

/// Row `i` of a valid covariance: 10⁻⁸ on the diagonal, small correlations beside it.
fn good_row(i: usize) -> String {
    let numbers: Vec<String> = (0..=i)
        .map(|j| {
            if j == i {
                "1e-8".to_string()
            } else {
                format!("{:e}", 1e-10 * ((i + j) % 3) as f64)
            }
        })
        .collect();
    format!("[{}]", numbers.join(", "))
}

#[test]
fn a_survey_covariance_parses_and_round_trips_through_to_toml() {
    let room = parse(&with_covariance(good_row), Path::new("room.toml")).unwrap();
    let covariance = &room.survey.as_ref().unwrap().covariance;
    assert_eq!(covariance.len(), 44);
    assert_eq!(covariance[43].len(), 44);
    assert_eq!(covariance[5][5], 1e-8);
    let text = to_toml(&room);
    assert!(text.contains("[survey]\n# the joint covariance"), "written under [survey]: {text}");
    let again = parse(&text, Path::new("again.toml")).unwrap();
    assert_eq!(again, room, "to_toml loses or changes something of the covariance");
}

#[test]
fn covariance_mistakes_name_the_row() {
    let short = |i: usize| if i == 7 { "[1e-8]".to_string() } else { good_row(i) };
    let nan = |i: usize| if i == 9 { good_row(9).replace("1e-8", "nan") } else { good_row(i) };
    let negative =
        |i: usize| if i == 12 { good_row(12).replace("1e-8", "-1e-8") } else { good_row(i) };
    let cases: [(String, &[&str]); 4] = [
        (with_covariance(short), &["survey.covariance", "row 7", "i + 1 numbers"]),
        (with_covariance(nan), &["survey.covariance", "row 9", "not finite"]),
        (with_covariance(negative), &["survey.covariance", "row 12", "negative"]),
        (
            with_covariance(good_row).replacen("[1e-8],\n", "", 1),
            &["survey.covariance", "6 per board + 4 per plane"],
        ),
    ];
    for (bad, words) in cases {
        let message = error_of(&bad);
        for w in words {
            assert!(message.contains(w), "`{w}` missing from: {message}");
        }
    }
}
