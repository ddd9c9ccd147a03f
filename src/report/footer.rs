//! The band added below the frame, so that no text hides the scene: the verdicts, figures
//! and refused planes' sentences on the left; the legend of the marks and one range colour
//! bar per LiDAR drawn on the right.

use image::{Rgb, RgbImage};

use super::draw::{diagonal_cross, dot, lines_height, outlined_cross, put, ring, Palette};
use super::{CONTOUR, CORNER, CORNER_OUTLINE, HOLE_CAMERA, HOLE_LIDAR, REFUSED, TEXT};
use crate::font;
use crate::geometry::Vec2;

/// The marks the legend explains, each drawn as in the picture.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Mark {
    Corner,
    HoleFromBoard,
    HoleFromLidar,
    /// The points of this many LiDARs ([`Palette::for_lidar`]).
    Points(usize),
    Refused,
    /// The projection map's contours.
    Contour,
}

/// One range colour bar: its title (which LiDAR) and its palette.
pub struct Bar {
    pub title: String,
    pub palette: Palette,
}

/// The frame above a footer: `left` lines (wrapped) on the left, the legend and the range
/// bars (from 0 to `range_max` metres; none without it) on the right.
pub fn with_footer(
    frame: &RgbImage,
    left: &[(String, Rgb<u8>)],
    legend: &[(Mark, String)],
    bars: &[Bar],
    range_max: Option<f64>,
    scale: u32,
) -> RgbImage {
    let s = i64::from(scale);
    let width = i64::from(frame.width());
    let split = width * 11 / 20;
    let chars = ((split - 20 * s) / i64::from(font::ADVANCE * scale)).max(10) as usize;
    let wrapped: Vec<(String, Rgb<u8>)> =
        left.iter().flat_map(|(t, c)| wrap(t, chars).into_iter().map(move |l| (l, *c))).collect();
    let bars = if range_max.is_some() { bars } else { &[] };
    let bar_height = range_bar_height(scale) + 6 * s;
    let right = lines_height(legend.len(), scale) + bar_height * bars.len() as i64;
    let footer = lines_height(wrapped.len(), scale).max(right) + 16 * s;
    let height = i64::from(frame.height()) + footer;
    let mut image = RgbImage::from_pixel(frame.width(), height as u32, Rgb([24, 24, 24]));
    image::imageops::replace(&mut image, frame, 0, 0);
    let top = i64::from(frame.height()) + 8 * s;
    for (k, (text, colour)) in wrapped.iter().enumerate() {
        font::draw_text(&mut image, 10 * s, top + lines_height(k, scale), scale, text, *colour);
    }
    let legend_height = draw_legend(&mut image, split, top, legend, scale);
    let length = width - split - 30 * s;
    for (k, bar) in bars.iter().enumerate() {
        let y = top + legend_height + 6 * s + k as i64 * bar_height;
        draw_range_bar(&mut image, (split, y), length, range_max.unwrap_or(5.0), bar, scale);
    }
    image
}

/// `text` broken at spaces into lines of at most `chars` characters, continuation lines
/// indented (a word longer than a line is cut).
fn wrap(text: &str, chars: usize) -> Vec<String> {
    const INDENT: &str = "    ";
    let mut lines = Vec::new();
    let mut current = String::new();
    for word in text.split(' ') {
        let word: String = word.chars().take(chars.saturating_sub(INDENT.len())).collect();
        if !current.is_empty() && current.chars().count() + 1 + word.chars().count() > chars {
            lines.push(std::mem::replace(&mut current, INDENT.to_string()));
        } else if !current.is_empty() {
            current.push(' ');
        }
        current.push_str(&word);
    }
    lines.push(current);
    lines
}

/// Height of a range bar with its title and tick labels.
fn range_bar_height(scale: u32) -> i64 {
    lines_height(2, scale) + 8 * i64::from(scale)
}

/// A colour scale of LiDAR points: a bar `length` pixels long from 0 to `max` metres in
/// the bar's palette, labelled ticks below it, its title above; top-left corner at `at`.
/// Every label is moved inside the image, so none is clipped.
fn draw_range_bar(
    image: &mut RgbImage,
    (x, y): (i64, i64),
    length: i64,
    max: f64,
    bar: &Bar,
    scale: u32,
) {
    let s = i64::from(scale);
    let line = lines_height(1, scale);
    let thick = 6 * s;
    font::draw_text(image, x, y, scale, &bar.title, TEXT);
    let bar_y = y + line;
    for i in 0..=length {
        let colour = bar.palette.colour(i as f64 / length as f64);
        for dy in 0..thick {
            put(image, x + i, bar_y + dy, colour);
        }
    }
    let step = if max <= 10.0 {
        1.0
    } else if max <= 30.0 {
        5.0
    } else {
        10.0
    };
    let ticks = (max / step).round() as i64;
    let width = i64::from(image.width());
    for k in 0..=ticks {
        let metres = k as f64 * step;
        let at = x + (metres / max * length as f64).round() as i64;
        for dy in thick..thick + 2 * s {
            put(image, at, bar_y + dy, TEXT);
        }
        let text = format!("{metres:.0}");
        let text_width = i64::from(font::text_width(&text, scale));
        let left = (at - text_width / 2).clamp(0, (width - text_width).max(0));
        font::draw_text(image, left, bar_y + thick + 3 * s, scale, &text, TEXT);
    }
}

/// The legend, each mark drawn as in the picture before its meaning; returns its height.
fn draw_legend(
    image: &mut RgbImage,
    x: i64,
    y: i64,
    entries: &[(Mark, String)],
    scale: u32,
) -> i64 {
    let s = i64::from(scale);
    let line = lines_height(1, scale);
    for (k, (mark, text)) in entries.iter().enumerate() {
        let top = y + k as i64 * line;
        let at = Vec2::new((x + 6 * s) as f64, (top + 3 * s) as f64);
        let colour = match mark {
            Mark::Corner => {
                outlined_cross(image, &at, 3 * s, CORNER, CORNER_OUTLINE);
                TEXT
            }
            Mark::HoleFromBoard => {
                ring(image, &at, 4.0 * s as f64, HOLE_CAMERA);
                HOLE_CAMERA
            }
            Mark::HoleFromLidar => {
                ring(image, &at, 3.0 * s as f64, HOLE_LIDAR);
                super::draw::cross(image, &at, 2 * s, HOLE_LIDAR);
                HOLE_LIDAR
            }
            Mark::Points(lidars) => {
                // Four dots: the rainbow's spread, or each LiDAR's family's near colour.
                for i in 0..4 {
                    let colour = match *lidars {
                        0 | 1 => Palette::Rainbow.colour(0.05 + 0.3 * i as f64),
                        n => Palette::for_lidar(i % n, n).colour(0.0),
                    };
                    let p = Vec2::new(at.x + (i as f64 - 1.5) * 3.0 * s as f64, at.y);
                    dot(image, &p, s / 2, colour);
                }
                TEXT
            }
            Mark::Refused => {
                diagonal_cross(image, &at, 3 * s, REFUSED);
                REFUSED
            }
            Mark::Contour => {
                for x in (at.x as i64 - 5 * s)..=(at.x as i64 + 5 * s) {
                    put(image, x, at.y as i64, CONTOUR);
                }
                CONTOUR
            }
        };
        font::draw_text(image, x + 16 * s, top, scale, text, colour);
    }
    lines_height(entries.len(), scale)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_bars_last_label_is_whole_at_the_pictures_edge() {
        // A bar running to the image's right edge, 0 to 15 m: its last label, "15", centred
        // on the last tick would be cut; it is moved in whole.
        let mut image = RgbImage::new(120, 40);
        let bar = Bar { title: "LiDAR".into(), palette: Palette::Rainbow };
        draw_range_bar(&mut image, (10, 0), 109, 15.0, &bar, 1);
        let lit = |c: char| font::glyph(c).iter().map(|r| r.count_ones() as usize).sum::<usize>();
        let labels_row = lines_height(1, 1) + 6 + 3;
        let drawn = (100..120)
            .flat_map(|x| (labels_row..labels_row + 7).map(move |y| (x, y)))
            .filter(|&(x, y)| image.get_pixel(x, y as u32).0 == TEXT.0)
            .count();
        assert_eq!(drawn, lit('1') + lit('5'));
    }

    #[test]
    fn the_footer_leaves_the_frame_untouched() {
        let frame = RgbImage::new(300, 50);
        let bar = Bar { title: "LiDAR".into(), palette: Palette::Rainbow };
        let legend = [(Mark::Points(1), "points".to_string())];
        let lines = [("ACCEPTED".to_string(), TEXT)];
        let image = with_footer(&frame, &lines, &legend, &[bar], Some(15.0), 1);
        assert!(image.height() > 50 + range_bar_height(1) as u32, "the bar below the frame");
        let frame_part = image::imageops::crop_imm(&image, 0, 0, 300, 50).to_image();
        assert!(frame_part.pixels().all(|p| p.0 == [0, 0, 0]));
    }

    #[test]
    fn long_lines_wrap_at_spaces_with_an_indent() {
        let lines = wrap("R1: plane of 102 points 6.0 m away", 16);
        assert_eq!(lines, vec!["R1: plane of 102", "    points 6.0 m", "    away"]);
    }
}
