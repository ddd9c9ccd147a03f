//! The room's big planes across visits: each visit's planes (found in its sweep, LiDAR
//! frame) are carried into the room by the visit's start pose and merged with the room
//! plane they agree with in direction and offset; a plane seen by fewer than
//! [`MIN_VISITS`] visits is left out. Each room plane is named from the first visit that
//! saw it, by its normal in that LiDAR's frame (x forward, y left, z up).

use crate::detect::planes::FoundPlane;
use crate::geometry::{Se3, Vec3};
use crate::solve::PlanePoints;
use crate::target::MAX_SURVEY_PLANES;

use super::bundle::RoomPlane;

/// Two planes whose normals differ by less than this (deg) and whose offsets by less
/// than [`SAME_OFFSET_M`] are one room plane. The start poses come from every board of the
/// visit (millimetres, a tenth of a degree); a room's walls differ by tens of degrees.
pub const SAME_ANGLE_DEG: f64 = 5.0;
pub const SAME_OFFSET_M: f64 = 0.2;
/// Fewest visits that must see a plane for it to be surveyed.
pub const MIN_VISITS: usize = 2;

/// One room plane: its start (the mean of its visits'), its name, how many visits saw it.
#[derive(Clone, Debug, PartialEq)]
pub struct AssociatedPlane {
    pub start: RoomPlane,
    pub name: String,
    pub visits: usize,
}

/// The room planes and, per visit, `(room plane, its points on it)`.
#[derive(Clone, Debug, PartialEq)]
pub struct RoomPlanes {
    pub planes: Vec<AssociatedPlane>,
    pub per_visit: Vec<Vec<(usize, PlanePoints)>>,
}

/// Associates the planes of every visit; `lidar_to_room[v]` is visit `v`'s start
/// (`None`: the visit's planes are not used).
pub fn associate(lidar_to_room: &[Option<Se3>], found: &[&[FoundPlane]]) -> RoomPlanes {
    // Candidate room planes: summed normal and offset of their members.
    struct Candidate {
        normal_sum: Vec3,
        offset_sum: f64,
        name: String,
        members: Vec<(usize, PlanePoints)>,
    }
    let mut candidates: Vec<Candidate> = Vec::new();
    for (v, (pose, planes)) in lidar_to_room.iter().zip(found).enumerate() {
        let Some(pose) = pose else { continue };
        let mut taken = vec![false; candidates.len()];
        for plane in planes.iter() {
            let (normal, offset) = in_room(pose, plane);
            let same = candidates.iter().enumerate().position(|(c, cand)| {
                let n = cand.normal_sum.normalize();
                let d = cand.offset_sum / cand.members.len() as f64;
                !taken[c]
                    && n.dot(&normal).clamp(-1.0, 1.0).acos().to_degrees() < SAME_ANGLE_DEG
                    && (d - offset).abs() < SAME_OFFSET_M
            });
            match same {
                Some(c) => {
                    taken[c] = true;
                    candidates[c].normal_sum += normal;
                    candidates[c].offset_sum += offset;
                    candidates[c].members.push((v, plane.points));
                }
                None => {
                    candidates.push(Candidate {
                        normal_sum: normal,
                        offset_sum: offset,
                        name: name_of(&plane.normal),
                        members: vec![(v, plane.points)],
                    });
                    taken.push(true);
                }
            }
        }
    }
    candidates.retain(|c| c.members.len() >= MIN_VISITS);
    candidates.sort_by_key(|c| core::cmp::Reverse(c.members.len()));
    candidates.truncate(MAX_SURVEY_PLANES);
    let mut out =
        RoomPlanes { planes: Vec::new(), per_visit: vec![Vec::new(); lidar_to_room.len()] };
    for (p, cand) in candidates.iter().enumerate() {
        let count = cand.members.len();
        let taken = out.planes.iter().filter(|q| q.name.starts_with(&cand.name)).count();
        let name =
            if taken == 0 { cand.name.clone() } else { format!("{} {}", cand.name, taken + 1) };
        out.planes.push(AssociatedPlane {
            start: RoomPlane {
                normal: cand.normal_sum.normalize(),
                offset: cand.offset_sum / count as f64,
            },
            name,
            visits: count,
        });
        for (v, points) in &cand.members {
            out.per_visit[*v].push((p, *points));
        }
    }
    out
}

/// A LiDAR-frame plane `n · p = d` in the room: `(R n) · p_room = d + (R n) · t`.
fn in_room(lidar_to_room: &Se3, plane: &FoundPlane) -> (Vec3, f64) {
    let normal = lidar_to_room.rotation * plane.normal;
    (normal, plane.offset + normal.dot(&lidar_to_room.translation))
}

/// A plane's name from its outward normal in a LiDAR frame (x forward, y left, z up).
fn name_of(normal: &Vec3) -> String {
    if normal.z < -0.8 {
        return "floor".into();
    }
    if normal.z > 0.8 {
        return "ceiling".into();
    }
    let heading = normal.y.atan2(normal.x).to_degrees();
    match heading {
        h if h.abs() <= 45.0 => "wall ahead",
        h if (45.0..=135.0).contains(&h) => "wall left",
        h if (-135.0..=-45.0).contains(&h) => "wall right",
        _ => "wall behind",
    }
    .into()
}
