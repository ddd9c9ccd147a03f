//! Where the picture's labels go ([`place_labels`]): each beside the point it names, on no
//! other label and inside the picture, so that no text is drawn over text.

/// A box in image pixels: its top-left corner, width and height.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Rect {
    pub x: i64,
    pub y: i64,
    pub w: i64,
    pub h: i64,
}

impl Rect {
    /// Whether the two boxes share a pixel (boxes that only touch do not).
    pub fn overlaps(&self, other: &Rect) -> bool {
        self.x < other.x + other.w
            && other.x < self.x + self.w
            && self.y < other.y + other.h
            && other.y < self.y + self.h
    }

    /// Whether the box lies wholly inside a `width` × `height` picture.
    pub fn inside(&self, width: i64, height: i64) -> bool {
        self.x >= 0 && self.y >= 0 && self.x + self.w <= width && self.y + self.h <= height
    }
}

/// One label to place: the pixel it names and its size (width, height).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LabelRequest {
    pub anchor: (i64, i64),
    pub size: (i64, i64),
}

/// Places the labels in order (earlier ones get the nearer spots): each in the first free
/// box of the candidates around its anchor — above, below, right, left, then the four
/// diagonals, at growing distances — moved inside the `picture` (width, height). A box is
/// free when it overlaps no label placed before it and none of `avoid` (the marks, which
/// a label covers only when no spot clear of them is left; a label never covers another).
/// `None` for a label with no free spot (a picture too small or too full).
pub fn place_labels(
    picture: (i64, i64),
    avoid: &[Rect],
    labels: &[LabelRequest],
) -> Vec<Option<Rect>> {
    let mut placed: Vec<Rect> = Vec::with_capacity(labels.len());
    let mut out = Vec::with_capacity(labels.len());
    for label in labels {
        let clear_of_marks = |r: &Rect| avoid.iter().all(|a| !a.overlaps(r));
        let spot = first_free(picture, label, &placed, clear_of_marks)
            .or_else(|| first_free(picture, label, &placed, |_| true));
        if let Some(r) = spot {
            placed.push(r);
        }
        out.push(spot);
    }
    out
}

/// The first candidate box for `label` inside the picture that overlaps none of `placed`
/// and passes `also`.
fn first_free(
    (width, height): (i64, i64),
    label: &LabelRequest,
    placed: &[Rect],
    also: impl Fn(&Rect) -> bool,
) -> Option<Rect> {
    let (w, h) = label.size;
    if w <= 0 || h <= 0 || w > width || h > height {
        return None;
    }
    // Rings a label's height apart (at least 4 px) out to where every candidate has been
    // moved against the picture's edge.
    let step = h.max(4);
    let rings = (width + height) / step + 2;
    (0..rings)
        .flat_map(|k| candidates(label, 4 + k * step))
        .map(|r| Rect { x: r.x.clamp(0, width - w), y: r.y.clamp(0, height - h), ..r })
        .find(|r| placed.iter().all(|p| !p.overlaps(r)) && also(r))
}

/// The eight boxes around the label's anchor at distance `d`, in the order tried.
fn candidates(label: &LabelRequest, d: i64) -> [Rect; 8] {
    let (ax, ay) = label.anchor;
    let (w, h) = label.size;
    let at = |x: i64, y: i64| Rect { x, y, w, h };
    let (centre_x, middle_y) = (ax - w / 2, ay - h / 2);
    let (above, below, right, left) = (ay - d - h, ay + d, ax + d, ax - d - w);
    [
        at(centre_x, above),
        at(centre_x, below),
        at(right, middle_y),
        at(left, middle_y),
        at(right, above),
        at(left, above),
        at(right, below),
        at(left, below),
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A small deterministic generator (no dependency for a test's random numbers).
    struct Lcg(u64);

    impl Lcg {
        fn below(&mut self, n: i64) -> i64 {
            self.0 = self.0.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((self.0 >> 33) % n.max(1) as u64) as i64
        }
    }

    fn assert_apart_and_inside(picture: (i64, i64), boxes: &[Rect]) {
        for (i, a) in boxes.iter().enumerate() {
            assert!(a.inside(picture.0, picture.1), "{a:?} outside {picture:?}");
            for b in &boxes[i + 1..] {
                assert!(!a.overlaps(b), "{a:?} overlaps {b:?}");
            }
        }
    }

    #[test]
    fn random_labels_never_overlap_and_stay_inside() {
        let mut rng = Lcg(7);
        for case in 0..400 {
            let picture = (200 + rng.below(1800), 150 + rng.below(1100));
            // Up to 60 labels; every fourth case crowds them into a small corner.
            let n = 1 + rng.below(60) as usize;
            let spread = if case % 4 == 0 { (80, 60) } else { picture };
            let labels: Vec<LabelRequest> = (0..n)
                .map(|_| LabelRequest {
                    anchor: (rng.below(spread.0) - 10, rng.below(spread.1) - 10),
                    size: (10 + rng.below(120), 10 + rng.below(20)),
                })
                .collect();
            let avoid: Vec<Rect> = (0..rng.below(8))
                .map(|_| Rect {
                    x: rng.below(picture.0),
                    y: rng.below(picture.1),
                    w: 20 + rng.below(200),
                    h: 20 + rng.below(150),
                })
                .collect();
            let placed = place_labels(picture, &avoid, &labels);
            assert_eq!(placed.len(), labels.len());
            let boxes: Vec<Rect> = placed.iter().flatten().copied().collect();
            assert_apart_and_inside(picture, &boxes);
            for (r, l) in placed.iter().zip(&labels) {
                if let Some(r) = r {
                    assert_eq!((r.w, r.h), l.size, "a label's box keeps its size");
                }
            }
            // Labels that together take under a tenth of the picture all find a spot.
            let area: i64 = labels.iter().map(|l| l.size.0 * l.size.1).sum();
            if area * 10 < picture.0 * picture.1 {
                assert!(placed.iter().all(Option::is_some), "case {case}: a label left out");
            }
        }
    }

    #[test]
    fn labels_on_one_anchor_stack_beside_it() {
        let label = LabelRequest { anchor: (500, 400), size: (40, 18) };
        let placed = place_labels((1000, 800), &[], &[label; 6]);
        let boxes: Vec<Rect> = placed.iter().map(|r| r.expect("room for six")).collect();
        assert_apart_and_inside((1000, 800), &boxes);
        // The first right above its anchor, centred; all within a few label heights.
        assert_eq!(boxes[0], Rect { x: 480, y: 400 - 4 - 18, w: 40, h: 18 });
        for r in &boxes {
            let (cx, cy) = (r.x + r.w / 2, r.y + r.h / 2);
            assert!((cx - 500).abs() < 120 && (cy - 400).abs() < 80, "{r:?} far from its anchor");
        }
    }

    #[test]
    fn a_label_keeps_off_a_mark_when_it_can_and_inside_at_the_edge() {
        let mark = Rect { x: 480, y: 360, w: 40, h: 40 };
        let label = LabelRequest { anchor: (500, 380), size: (30, 10) };
        let r = place_labels((1000, 800), &[mark], &[label])[0].unwrap();
        assert!(!r.overlaps(&mark), "{r:?} on the mark");
        // An anchor outside the picture: the label is moved in.
        let out = LabelRequest { anchor: (-50, 900), size: (30, 10) };
        let r = place_labels((1000, 800), &[], &[out])[0].unwrap();
        assert!(r.inside(1000, 800), "{r:?}");
        // A label wider than the picture has no spot.
        let wide = LabelRequest { anchor: (10, 10), size: (2000, 10) };
        assert_eq!(place_labels((1000, 800), &[], &[wide]), vec![None]);
    }
}
