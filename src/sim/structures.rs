//! Structures that are no board but leave evidence a board detector could misread: flat,
//! board-sized and full of gaps a hole's width across. Each is built of the world's
//! axis-aligned boxes, its face in a plane `x = const` facing the sensor, so seen from an
//! azimuth off the x axis it is turned by that azimuth.
//!
//! - [`Structure::PostAndPatches`]: a post and two small patches whose gaps fall on the
//!   room board's hole lattice, the structure a real sweep once showed where a board was
//!   placed that was not there: scan lines cross where the board's face would be, and
//!   return from almost none of it.
//! - [`Structure::Fence`]: pickets a hole's width apart on two rails.
//! - [`Structure::Railing`]: posts and three rails.
//! - [`Structure::Shelving`]: uprights, deep shelves and a few boxes on them.
//! - [`Structure::Window`]: a wall whose window is panes (no returns through glass)
//!   between mullions and a transom.
//! - [`Structure::Doorway`]: a wall with a door-sized opening.

use crate::geometry::Vec3;
use crate::target::BoardSpec;

use super::rng::Rng;
use super::world::World;

/// A kind of structure ([`add`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Structure {
    PostAndPatches,
    Fence,
    Railing,
    Shelving,
    Window,
    Doorway,
}

impl Structure {
    /// Every kind, in a fixed order (what a random room draws from).
    pub const ALL: [Structure; 6] = [
        Structure::PostAndPatches,
        Structure::Fence,
        Structure::Railing,
        Structure::Shelving,
        Structure::Window,
        Structure::Doorway,
    ];
}

/// Where a structure stands: the middle of its face's foot at (`x`, `y`) on the floor
/// (`floor_z`, LiDAR frame); its face is the plane `x` = const nearest the sensor.
#[derive(Clone, Copy, Debug)]
pub struct Site {
    pub x: f64,
    pub y: f64,
    pub floor_z: f64,
}

/// How much room a structure takes: half its width along y and its depth along x (m).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Footprint {
    pub half_width: f64,
    pub depth: f64,
}

/// Draws the sizes of `kind` from `rng` and adds it to `world` at `site`; `spec` is the
/// room's board, whose hole lattice [`Structure::PostAndPatches`] copies. The post and
/// patches stand at the sensor's own height (z = 0), where boards are seen best.
pub fn add(
    world: &mut World,
    kind: Structure,
    spec: &BoardSpec,
    site: Site,
    rng: &mut Rng,
) -> Footprint {
    let mut face = Face { world, site };
    match kind {
        Structure::PostAndPatches => face.post_and_patches(spec),
        Structure::Fence => face.fence(rng),
        Structure::Railing => face.railing(rng),
        Structure::Shelving => face.shelving(rng),
        Structure::Window => face.window(rng),
        Structure::Doorway => face.doorway(rng),
    }
}

/// A structure's face being built: boxes given across (along y, about the site) and up
/// (above the floor).
struct Face<'a> {
    world: &'a mut World,
    site: Site,
}

impl Face<'_> {
    /// A box spanning `across` (y about the site), `up` (z above the floor) and `depth`
    /// behind the face (x).
    fn slab(&mut self, across: (f64, f64), up: (f64, f64), depth: (f64, f64)) {
        let s = self.site;
        self.world.add_box(
            Vec3::new(s.x + depth.0, s.y + across.0, s.floor_z + up.0),
            Vec3::new(s.x + depth.1, s.y + across.1, s.floor_z + up.1),
        );
    }

    /// A post between the hole columns nearest the middle and two patches just outside
    /// the outer columns, as tall as the hole rows: every gap between them is a hole's
    /// width at a hole's place, the face around them empty.
    fn post_and_patches(&mut self, spec: &BoardSpec) -> Footprint {
        let r = spec.hole_radius;
        let xs = spec.holes.iter().map(|h| h[0].abs());
        let (inner, outer) = xs.fold((f64::MAX, 0.0f64), |(i, o), x| (i.min(x), o.max(x)));
        let ys = spec.holes.iter().map(|h| h[1]);
        let (top, bottom) = ys.fold((f64::MAX, f64::MIN), |(t, b), y| (t.min(y), b.max(y)));
        // The board's centre at the sensor's height; board y points down.
        let centre = -self.site.floor_z;
        let post = (inner - r - 0.02).clamp(0.03, 0.15);
        let depth = (0.0, 0.08);
        self.slab((-post, post), (0.0, centre + spec.height / 2.0 + 0.5), depth);
        let rows = (centre - bottom - r, centre - top + r);
        for side in [-1.0, 1.0] {
            let (a, b) = (side * (outer + r + 0.02), side * (outer + r + 0.12));
            self.slab((a.min(b), a.max(b)), rows, depth);
        }
        Footprint { half_width: outer + r + 0.12, depth: depth.1 }
    }

    /// Pickets 6–12 cm wide, 8–25 cm apart, 1–1.8 m tall, on two rails behind them.
    fn fence(&mut self, rng: &mut Rng) -> Footprint {
        let (width, gap, height) =
            (rng.range(0.06, 0.12), rng.range(0.08, 0.25), rng.range(1.0, 1.8));
        let half = rng.range(1.0, 2.0);
        let mut y = -half;
        while y + width <= half {
            self.slab((y, y + width), (0.05, height), (0.0, 0.02));
            y += width + gap;
        }
        for z in [0.25, height - 0.25] {
            self.slab((-half, half), (z, z + 0.06), (0.02, 0.06));
        }
        Footprint { half_width: half, depth: 0.06 }
    }

    /// Square posts every 1–1.5 m and rails at three heights up to 1.1 m.
    fn railing(&mut self, rng: &mut Rng) -> Footprint {
        let (spacing, half) = (rng.range(1.0, 1.5), rng.range(1.0, 2.0));
        let mut y = -half;
        while y <= half {
            self.slab((y - 0.025, y + 0.025), (0.0, 1.1), (0.0, 0.05));
            y += spacing;
        }
        for z in [0.1, 0.55, 1.05] {
            self.slab((-half, half), (z, z + 0.05), (0.0, 0.05));
        }
        Footprint { half_width: half, depth: 0.05 }
    }

    /// Two uprights, shelves 30–50 cm apart and 40 cm deep, now and then a box on a shelf.
    fn shelving(&mut self, rng: &mut Rng) -> Footprint {
        let (half, height, pitch) = (rng.range(0.5, 0.9), rng.range(1.8, 2.2), rng.range(0.3, 0.5));
        let depth = (0.0, 0.4);
        for side in [-1.0, 1.0] {
            let y = side * half;
            self.slab((y - 0.02, y + 0.02), (0.0, height), depth);
        }
        let mut z = 0.1;
        while z < height {
            self.slab((-half, half), (z, z + 0.03), depth);
            if rng.uniform() < 0.5 {
                let (w, h) = (rng.range(0.15, 0.4), rng.range(0.1, pitch - 0.05));
                let y = rng.range(-half + 0.05, half - 0.05 - w);
                self.slab((y, y + w), (z + 0.03, z + 0.03 + h), (rng.range(0.02, 0.15), 0.38));
            }
            z += pitch;
        }
        Footprint { half_width: half + 0.02, depth: depth.1 }
    }

    /// A wall 2.6 m high, 0.1 m thick, with a window from 0.9 to 2.1 m: panes 0.4–0.9 m
    /// wide between mullions 5–10 cm wide, and a transom across its middle.
    fn window(&mut self, rng: &mut Rng) -> Footprint {
        let half = rng.range(1.25, 2.0);
        let (sill, head, top) = (0.9, 2.1, 2.6);
        let depth = (0.0, 0.1);
        self.slab((-half, half), (0.0, sill), depth);
        self.slab((-half, half), (head, top), depth);
        let jamb = 0.3;
        for side in [-1.0, 1.0] {
            let (a, b) = (side * half, side * (half - jamb));
            self.slab((a.min(b), a.max(b)), (sill, head), depth);
        }
        let (opening, mullion) = (2.0 * (half - jamb), rng.range(0.05, 0.1));
        let panes = (opening / rng.range(0.4, 0.9)).round().max(1.0);
        let pane = (opening - (panes - 1.0) * mullion) / panes;
        for k in 1..panes as usize {
            let y = -half + jamb + k as f64 * (pane + mullion) - mullion;
            self.slab((y, y + mullion), (sill, head), (0.02, 0.08));
        }
        let middle = (sill + head) / 2.0;
        self.slab((-half, half), (middle - mullion / 2.0, middle + mullion / 2.0), (0.02, 0.08));
        Footprint { half_width: half, depth: depth.1 }
    }

    /// A wall 2.5 m high, 0.1 m thick, with an opening 0.8–1 m wide and 2–2.1 m high
    /// somewhere along it.
    fn doorway(&mut self, rng: &mut Rng) -> Footprint {
        let (half, door, door_height) =
            (rng.range(1.25, 2.0), rng.range(0.8, 1.0), rng.range(2.0, 2.1));
        let top = 2.5;
        let depth = (0.0, 0.1);
        let left = rng.range(-half + 0.2, half - 0.2 - door);
        self.slab((-half, left), (0.0, top), depth);
        self.slab((left + door, half), (0.0, top), depth);
        self.slab((left, left + door), (door_height, top), depth);
        Footprint { half_width: half, depth: depth.1 }
    }
}
