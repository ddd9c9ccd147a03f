//! The rig problem: every camera and every LiDAR of one vehicle in a surveyed room, one
//! joint least-squares problem. The calibration of one pair in the surveyed room is this
//! problem with one camera, one LiDAR and one frame ([`super::room`]).
//!
//! Unknowns (shared, in this order, [`RigLayout`]): per camera its intrinsics and
//! distortion (9); per camera but the first its mounting first camera → camera (6); per
//! LiDAR its mounting LiDAR → first camera (6); per frame (a parking of the vehicle) the
//! room → first camera pose (6). Blocks, eliminated by the Schur complement
//! ([`super::schur`]): every surveyed board and plane in the room frame, held near the
//! survey by its prior ([`BlockPrior`], σ the survey's).
//!
//! Every measurement is a [`BoardObservation`] of the free-board problem, seen by camera
//! `c` with
//! - board → camera `c` = `A_c ∘ R_f ∘ K_k` (first → `c`, room → first in frame `f`,
//!   block `k` → room), and
//! - LiDAR → camera `c` = `A_c ∘ E_l` (`E_l`: LiDAR `l` → first),
//!
//! so the corner, hole and point-to-plane blocks and their analytic Jacobians are the
//! free-board ones ([`BoardObservation::for_each_residual`]), carried to these unknowns by
//! the chain rule of the left perturbation (`R ← exp(δω) R`, `t ← t + δt`) of `C = A ∘ B`
//! ([`chain`]):
//! - `δA` moves `C` by `δω_C = δω_A`, `δt_C = δt_A − [R_A t_B]× δω_A`;
//! - `δB` moves `C` by `δω_C = R_A δω_B`, `δt_C = R_A δt_B`.
//!
//! Corners and holes are pixels of the observation's camera; a LiDAR's board or plane
//! that no camera shares enters as its point-to-plane term alone (through the first
//! camera's frame, no intrinsics). Sensors whose views never overlap are tied through the
//! room. The first camera's mounting is the identity, not a parameter.
//!
//! A surveyed plane `n · p = d` is a block whose frame has its z axis along `n` and its
//! origin at `d n` ([`plane_frame`]): the LiDAR points near it are a board-face term with
//! that pose. Its in-plane rotation and shift are seen by nothing but their prior.
//!
//! Without a survey every block is a free board ([`BlockPrior::free`]): nothing holds it
//! but its measurements, so the room frame is undetermined; the problem then holds frame
//! 0's room → first camera pose at its start (the gauge: the room frame is the first
//! camera's in frame 0 when that start is the identity), and sensors are tied through the
//! boards they both see. Such a block needs corners (6 constraints) or its `U_k` is
//! singular; [`RigProblem::add_observation`] cannot know that, the caller keeps to it.
//!
//! Capacities are const generics: `C` cameras, `L` LiDARs, `F` frames, `B` blocks, `O`
//! observations, and `N` = [`rig_shared`]`(C, L, F)` shared parameters (checked at compile
//! time: stable Rust cannot compute it from the others in a type). Nothing here allocates.

use nalgebra::{SMatrix, SVector};

use super::covariance::kinds_covariance;
use super::linalg::max_eigenvalue3;
use super::minimize::Settings;
use super::problem::{BoardObservation, Loss, Noise, ResidualKind};
use super::schur::{self, SchurProblem, SchurSystem};
use super::{Projector, SolveError, EXT_ROTATION, INTRINSICS, SHARED};
use crate::geometry::se3::{skew, so3_left_jacobian_inv, so3_log};
use crate::geometry::{Mat3, Se3, Vec2, Vec3};

/// Shared parameters of a rig of `cameras` (at least one), `lidars` and `frames`.
pub const fn rig_shared(cameras: usize, lidars: usize, frames: usize) -> usize {
    INTRINSICS * cameras + 6 * (cameras - 1) + 6 * lidars + 6 * frames
}

/// Where each unknown sits in the shared vector of a rig of these capacities.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RigLayout {
    pub cameras: usize,
    pub lidars: usize,
    pub frames: usize,
}

impl RigLayout {
    /// Camera `c`'s `[fx fy cx cy d0..d4]`.
    pub const fn intrinsics(&self, c: usize) -> usize {
        INTRINSICS * c
    }
    /// Camera `c`'s mounting first → `c` `[δω δt]` (`c ≥ 1`).
    pub const fn camera_pose(&self, c: usize) -> usize {
        INTRINSICS * self.cameras + 6 * (c - 1)
    }
    /// LiDAR `l`'s mounting LiDAR → first `[δω δt]`.
    pub const fn lidar_pose(&self, l: usize) -> usize {
        INTRINSICS * self.cameras + 6 * (self.cameras - 1) + 6 * l
    }
    /// Frame `f`'s room → first camera `[δω δt]`.
    pub const fn frame_pose(&self, f: usize) -> usize {
        self.lidar_pose(self.lidars) + 6 * f
    }
    /// Length of the shared vector.
    pub const fn len(&self) -> usize {
        rig_shared(self.cameras, self.lidars, self.frames)
    }
    /// Whether the layout holds no parameter (never: a rig has a camera and a frame).
    pub const fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// Smallest prior σ used (m, rad): an exact survey (σ = 0) holds its block this tightly.
pub const PRIOR_FLOOR: f64 = 1e-6;

/// What the survey says about one block: its pose (block → room) and its 1σ.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BlockPrior {
    pub pose: Se3,
    /// Position σ (m), every axis.
    pub sigma_m: f64,
    /// Orientation σ (rad), every axis.
    pub sigma_rad: f64,
}

impl BlockPrior {
    /// A block nothing holds (a free board): infinite σ, so its prior rows weigh nothing;
    /// `pose` is only the start.
    pub fn free(pose: Se3) -> BlockPrior {
        BlockPrior { pose, sigma_m: f64::INFINITY, sigma_rad: f64::INFINITY }
    }

    /// Whether nothing holds the block ([`BlockPrior::free`]).
    pub fn is_free(&self) -> bool {
        self.sigma_m == f64::INFINITY && self.sigma_rad == f64::INFINITY
    }

    /// Scalar residuals the prior adds: 6, none for a free block.
    pub fn rows(&self) -> usize {
        if self.is_free() {
            0
        } else {
            6
        }
    }
}

/// The frame of the plane `normal · p = offset`: z along the (unit) normal, origin at
/// `offset · normal`; x, y any orthonormal completion.
pub fn plane_frame(normal: &Vec3, offset: f64) -> Se3 {
    let z = normal.normalize();
    let helper = if z.x.abs() < 0.9 { Vec3::x() } else { Vec3::y() };
    let x = helper.cross(&z).normalize();
    let y = z.cross(&x);
    Se3 { rotation: Mat3::from_columns(&[x, y, z]), translation: z * offset }
}

/// How the rig problem is solved (and the room modes, [`super::room_modes`]): Marquardt's
/// schedule; stop when an accepted step lowers the cost by at most 10⁻⁹ of it, the
/// tolerance the surveyed-room and rig results were validated with. No gradient or step
/// test: the cost test and the λ cap end every solve.
pub const SETTINGS: Settings = Settings { cost_tolerance: 1e-9, ..Settings::MARQUARDT };

/// One board observation of a rig: which frame, block, camera and LiDAR it belongs to.
#[derive(Clone, Copy, Debug, Default)]
pub struct RigObservation<'a> {
    pub frame: usize,
    pub block: usize,
    /// The camera whose pixels carry the corner and hole terms; `None` for a LiDAR's
    /// point-to-plane term alone.
    pub camera: Option<usize>,
    /// The LiDAR whose holes and points these are (`None`: corners only).
    pub lidar: Option<usize>,
    pub observation: BoardObservation<'a>,
}

/// The estimate of a rig problem.
#[derive(Clone, Debug)]
pub struct RigParams<K, const C: usize, const L: usize, const F: usize, const B: usize> {
    pub cameras: [K; C],
    /// First camera → camera `c`: `p_c = R p_first + t` (entry 0 stays the identity).
    pub first_to_camera: [Se3; C],
    /// LiDAR `l` → first camera: `p_first = R p_lidar + t`.
    pub lidar_to_first: [Se3; L],
    /// Room → first camera, per frame.
    pub room_to_first: [Se3; F],
    /// Block → room, one per block in the problem's order.
    pub blocks: heapless::Vec<Se3, B>,
}

/// Observations by reference, the blocks' priors, the noise and the loss.
#[derive(Clone, Debug)]
pub struct RigProblem<
    'a,
    const C: usize,
    const L: usize,
    const F: usize,
    const B: usize,
    const O: usize,
    const N: usize,
> {
    observations: heapless::Vec<RigObservation<'a>, O>,
    priors: heapless::Vec<BlockPrior, B>,
    /// Per camera, its corner σ (px).
    pub corner_sigma_px: [f64; C],
    /// The hole term's σ (px) where an observation does not set its own.
    pub hole_sigma_px: f64,
    /// Robust loss of the corner and hole blocks.
    pub loss: Loss,
}

/// What a rig solve did.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RigReport<const C: usize, const L: usize> {
    pub iterations: usize,
    pub initial_cost: f64,
    pub final_cost: f64,
    /// Scalar residuals (measurements and prior rows).
    pub residuals: usize,
    /// Plain RMS pixel error of each camera's corners, and of each LiDAR's hole term.
    pub corner_rms_px: [f64; C],
    pub hole_rms_px: [f64; L],
}

/// The covariance of a rig's shared parameters (left perturbations for the poses).
#[derive(Clone, Debug)]
pub struct RigCovariance<const N: usize> {
    pub layout: RigLayout,
    pub matrix: SMatrix<f64, N, N>,
}

impl<
        'a,
        const C: usize,
        const L: usize,
        const F: usize,
        const B: usize,
        const O: usize,
        const N: usize,
    > RigProblem<'a, C, L, F, B, O, N>
{
    /// The layout of the shared vector.
    pub const LAYOUT: RigLayout = RigLayout { cameras: C, lidars: L, frames: F };
    const SIZES_AGREE: () = assert!(C >= 1 && F >= 1 && N == rig_shared(C, L, F));

    /// An empty problem: every camera's corner σ, the default hole σ (px) and the loss.
    pub fn new(corner_sigma_px: [f64; C], hole_sigma_px: f64, loss: Loss) -> Self {
        let () = Self::SIZES_AGREE;
        RigProblem {
            observations: heapless::Vec::new(),
            priors: heapless::Vec::new(),
            corner_sigma_px,
            hole_sigma_px,
            loss,
        }
    }

    /// Adds a block (surveyed board or plane) with its prior; returns its index. Blocks
    /// are all surveyed or all free ([`BlockPrior::free`]).
    pub fn add_block(&mut self, prior: BlockPrior) -> Result<usize, SolveError> {
        let positive = |v: f64| v.is_finite() && v >= 0.0;
        let surveyed = positive(prior.sigma_m) && positive(prior.sigma_rad);
        if !surveyed && !prior.is_free() {
            return Err(SolveError::BadSetting("survey σ must be non-negative"));
        }
        if self.priors.first().is_some_and(|p| p.is_free() != prior.is_free()) {
            return Err(SolveError::BadSetting("blocks are all surveyed or all free"));
        }
        self.priors.push(prior).map_err(|_| SolveError::TooManyBoards { capacity: B })?;
        Ok(self.priors.len() - 1)
    }

    /// Adds an observation; returns its index. Corners need a camera, holes a camera and
    /// a LiDAR, a plane term a LiDAR.
    pub fn add_observation(&mut self, o: RigObservation<'a>) -> Result<usize, SolveError> {
        o.observation.check()?;
        let index = self.observations.len();
        let bad = |what| Err(SolveError::BadBoard { board: index, what });
        let obs = &o.observation;
        if o.block >= self.priors.len() {
            return bad("no such block");
        }
        if o.frame >= F || o.camera.is_some_and(|c| c >= C) || o.lidar.is_some_and(|l| l >= L) {
            return bad("frame, camera or LiDAR beyond the rig problem's capacity");
        }
        if !obs.corners.is_empty() && o.camera.is_none() {
            return bad("corners without the camera that saw them");
        }
        if !obs.holes_lidar.is_empty() && (o.camera.is_none() || o.lidar.is_none()) {
            return bad("holes need their LiDAR and a camera to be seen in");
        }
        if obs.plane.is_some() && o.lidar.is_none() {
            return bad("plane points without their LiDAR");
        }
        self.observations.push(o).map_err(|_| SolveError::TooManyBoards { capacity: O })?;
        Ok(index)
    }

    /// The blocks' priors, in order.
    pub fn priors(&self) -> &[BlockPrior] {
        &self.priors
    }

    /// The observations, in order.
    pub fn observations(&self) -> &[RigObservation<'a>] {
        &self.observations
    }

    /// Params with every block at its prior.
    pub fn params_at_priors<K>(
        &self,
        cameras: [K; C],
        first_to_camera: [Se3; C],
        lidar_to_first: [Se3; L],
        room_to_first: [Se3; F],
    ) -> RigParams<K, C, L, F, B> {
        let blocks = self.priors.iter().map(|p| p.pose).collect();
        RigParams { cameras, first_to_camera, lidar_to_first, room_to_first, blocks }
    }

    /// Calls `f(block, kind, whitened residual, ∂r/∂shared (2×N), ∂r/∂block (2×6), rows)`
    /// for every measurement block.
    pub fn for_each_residual<K: Projector>(
        &self,
        params: &RigParams<K, C, L, F, B>,
        mut f: impl FnMut(usize, ResidualKind, &Vec2, &SMatrix<f64, 2, N>, &SMatrix<f64, 2, 6>, usize),
    ) -> Result<(), SolveError> {
        self.check(params)?;
        let at = Self::LAYOUT;
        for (index, o) in self.observations.iter().enumerate() {
            let g = self.geometry(params, o);
            let c = o.camera.unwrap_or(0);
            let (m_a, m_m) = chain(&g.mount, &g.room_block);
            let (m_r, m_k) = chain(&params.room_to_first[o.frame], &params.blocks[o.block]);
            let (e_a, e_e) = chain(&g.mount, &g.lidar);
            let (to_frame, to_block) = (m_m * m_r, m_m * m_k);
            let noise = self.noise(c);
            o.observation.for_each_residual(
                index,
                &params.cameras[c],
                &g.ext,
                &g.pose,
                noise,
                &mut |res| {
                    let mut js = SMatrix::<f64, 2, N>::zeros();
                    if o.camera.is_some() {
                        js.fixed_view_mut::<2, INTRINSICS>(0, at.intrinsics(c))
                            .copy_from(&res.j_shared.fixed_view::<2, INTRINSICS>(0, 0));
                    }
                    let j_ext = res.j_shared.fixed_view::<2, 6>(0, EXT_ROTATION).into_owned();
                    if c > 0 {
                        js.fixed_view_mut::<2, 6>(0, at.camera_pose(c))
                            .copy_from(&(res.j_board * m_a + j_ext * e_a));
                    }
                    if let Some(l) = o.lidar {
                        js.fixed_view_mut::<2, 6>(0, at.lidar_pose(l)).copy_from(&(j_ext * e_e));
                    }
                    js.fixed_view_mut::<2, 6>(0, at.frame_pose(o.frame))
                        .copy_from(&(res.j_board * to_frame));
                    f(o.block, res.kind, &res.r, &js, &(res.j_board * to_block), res.rows);
                },
            )?;
        }
        Ok(())
    }

    /// Calls `f(block, whitened prior residual, its Jacobian)` for every block.
    pub fn for_each_prior<K>(
        &self,
        params: &RigParams<K, C, L, F, B>,
        mut f: impl FnMut(usize, &SVector<f64, 6>, &SMatrix<f64, 6, 6>),
    ) {
        for (k, (prior, pose)) in self.priors.iter().zip(params.blocks.iter()).enumerate() {
            let (r, j) = prior_residual(prior, pose);
            f(k, &r, &j);
        }
    }

    /// Calls `f(observation, kind, error)` for every block, plain (no σ, no loss).
    pub fn for_each_error<K: Projector>(
        &self,
        params: &RigParams<K, C, L, F, B>,
        mut f: impl FnMut(&RigObservation<'a>, ResidualKind, Vec2),
    ) -> Result<(), SolveError> {
        self.check(params)?;
        for (index, o) in self.observations.iter().enumerate() {
            let g = self.geometry(params, o);
            let camera = &params.cameras[o.camera.unwrap_or(0)];
            o.observation
                .for_each_error(index, camera, &g.ext, &g.pose, &mut |kind, e| f(o, kind, e))?;
        }
        Ok(())
    }

    /// Robust cost of the measurements alone, `½ Σ ρ(|r/σ|²)`.
    pub fn measurement_cost<K: Projector>(
        &self,
        params: &RigParams<K, C, L, F, B>,
    ) -> Result<f64, SolveError> {
        let mut cost = 0.0;
        self.for_each_error(params, |o, kind, e| {
            let whitened = e / o.observation.sigma(kind, self.noise(o.camera.unwrap_or(0)));
            cost += 0.5 * self.loss_for(kind).eval(whitened.norm_squared()).0;
        })?;
        finite(cost)
    }

    /// Robust cost: the measurements' ([`Self::measurement_cost`]) plus `½ |prior|²`.
    pub fn cost<K: Projector>(&self, params: &RigParams<K, C, L, F, B>) -> Result<f64, SolveError> {
        let mut cost = self.measurement_cost(params)?;
        self.for_each_prior(params, |_, r, _| cost += 0.5 * r.norm_squared());
        finite(cost)
    }

    /// Adds the measurements' normal equations (no prior) to `ne` (made for this problem's
    /// blocks; its prior rows are whoever adds the priors': the survey's, or the room's
    /// modes). In place: a rig's system is 0.2 MB, and a calibration runs on a 2 MiB worker
    /// thread, where a system returned by value is one more copy on the stack.
    pub fn add_measurements<K: Projector>(
        &self,
        params: &RigParams<K, C, L, F, B>,
        ne: &mut SchurSystem<N, B>,
    ) -> Result<(), SolveError> {
        self.for_each_residual(params, |k, kind, r, js, jb, rows| {
            ne.add(k, self.loss_for(kind), r, js, jb, rows);
        })
    }

    /// The loss a measurement kind is weighed with: the problem's, but the plane term's
    /// plain least squares ([`ResidualKind::loss`]).
    pub fn loss_for(&self, kind: ResidualKind) -> Loss {
        kind.loss(self.loss)
    }

    /// Per block, `(measurement cost, prior cost)` at `params` (`½ Σ ρ` of its whitened
    /// blocks), for naming a block that disagrees with the survey.
    pub fn block_costs<K: Projector>(
        &self,
        params: &RigParams<K, C, L, F, B>,
    ) -> Result<heapless::Vec<(f64, f64), B>, SolveError> {
        let mut out: heapless::Vec<(f64, f64), B> =
            self.priors.iter().map(|_| (0.0, 0.0)).collect();
        self.for_each_residual(params, |k, kind, r, _, _, _| {
            out[k].0 += 0.5 * self.loss_for(kind).eval(r.norm_squared()).0;
        })?;
        self.for_each_prior(params, |k, r, _| out[k].1 += 0.5 * r.norm_squared());
        Ok(out)
    }

    /// Board → camera of every observation, in order (seen by its camera; by the first
    /// camera for a LiDAR's plane term alone).
    pub fn board_poses<K: Projector>(
        &self,
        params: &RigParams<K, C, L, F, B>,
    ) -> Result<heapless::Vec<Se3, O>, SolveError> {
        self.check(params)?;
        Ok(self.observations.iter().map(|o| self.geometry(params, o).pose).collect())
    }

    /// Whether LiDAR `l` is measured (a hole or a plane term); otherwise nothing sees its
    /// mounting.
    pub fn sees_lidar(&self, l: usize) -> bool {
        self.observations.iter().any(|o| {
            o.lidar == Some(l)
                && (!o.observation.holes_lidar.is_empty() || o.observation.plane.is_some())
        })
    }

    /// Shared parameters nothing moves: the unused intrinsics of each camera's model, the
    /// mounting of a LiDAR nothing measures, and frame 0's room pose when the blocks are
    /// free (the gauge).
    pub fn structural_mask<K: Projector>(&self, params: &RigParams<K, C, L, F, B>) -> [bool; N] {
        let at = Self::LAYOUT;
        let mut fixed = [false; N];
        for (c, camera) in params.cameras.iter().enumerate() {
            let used = camera.num_params().min(INTRINSICS);
            for f in fixed.iter_mut().skip(at.intrinsics(c) + used).take(INTRINSICS - used) {
                *f = true;
            }
        }
        for l in (0..L).filter(|&l| !self.sees_lidar(l)) {
            fixed[at.lidar_pose(l)..at.lidar_pose(l) + 6].fill(true);
        }
        if self.holds_first_frame() {
            fixed[at.frame_pose(0)..at.frame_pose(0) + 6].fill(true);
        }
        fixed
    }

    /// Plain RMS pixel error of each camera's corners and of each LiDAR's hole term (0
    /// where there are none).
    pub fn rms_px<K: Projector>(
        &self,
        params: &RigParams<K, C, L, F, B>,
    ) -> Result<([f64; C], [f64; L]), SolveError> {
        let (mut corners, mut holes) = ([(0.0, 0usize); C], [(0.0, 0usize); L]);
        self.for_each_error(params, |o, kind, e| {
            let slot = match (kind, o.camera, o.lidar) {
                (ResidualKind::Corner(_), Some(c), _) => &mut corners[c],
                (ResidualKind::Hole(_), _, Some(l)) => &mut holes[l],
                _ => return,
            };
            slot.0 += e.norm_squared();
            slot.1 += 1;
        })?;
        let rms = |(s, n): (f64, usize)| if n == 0 { 0.0 } else { libm::sqrt(s / n as f64) };
        Ok((corners.map(rms), holes.map(rms)))
    }

    /// Scalar residuals: measurements and 6 prior rows per surveyed block.
    pub fn residual_count(&self) -> usize {
        let measured: usize =
            self.observations.iter().map(|o| o.observation.residual_count()).sum();
        measured + self.prior_rows()
    }

    /// Whether the blocks are free boards, so frame 0's room pose is held (the gauge).
    pub fn holds_first_frame(&self) -> bool {
        self.priors.first().is_some_and(BlockPrior::is_free)
    }

    fn prior_rows(&self) -> usize {
        self.priors.iter().map(BlockPrior::rows).sum()
    }

    fn noise(&self, camera: usize) -> Noise {
        Noise { corner_px: self.corner_sigma_px[camera], hole_px: self.hole_sigma_px }
    }

    fn check<K>(&self, params: &RigParams<K, C, L, F, B>) -> Result<(), SolveError> {
        if params.blocks.len() != self.priors.len() {
            return Err(SolveError::LengthMismatch {
                left: self.priors.len(),
                right: params.blocks.len(),
            });
        }
        let positive = |v: f64| v.is_finite() && v > 0.0;
        let own_hole_sigmas = self.observations.iter().filter_map(|o| o.observation.hole_sigma_px);
        if !self.corner_sigma_px.iter().all(|&s| positive(s))
            || !positive(self.hole_sigma_px)
            || !own_hole_sigmas.into_iter().all(positive)
        {
            return Err(SolveError::BadSetting("corner and hole σ must be positive"));
        }
        if let Loss::Huber(c) | Loss::Cauchy(c) = self.loss {
            if !positive(c) {
                return Err(SolveError::BadSetting("robust loss scale must be positive"));
            }
        }
        Ok(())
    }

    /// The poses an observation is evaluated with.
    fn geometry<K>(&self, params: &RigParams<K, C, L, F, B>, o: &RigObservation<'_>) -> Geometry {
        let mount = match o.camera {
            Some(c) if c > 0 => params.first_to_camera[c],
            _ => Se3::identity(),
        };
        let lidar = o.lidar.map_or_else(Se3::identity, |l| params.lidar_to_first[l]);
        let room_block = params.room_to_first[o.frame].compose(&params.blocks[o.block]);
        Geometry {
            mount,
            lidar,
            room_block,
            pose: mount.compose(&room_block),
            ext: mount.compose(&lidar),
        }
    }
}

/// Observation `o`'s poses: `A_c`, `E_l`, `R_f ∘ K_k`, board → camera and LiDAR → camera.
struct Geometry {
    mount: Se3,
    lidar: Se3,
    room_block: Se3,
    pose: Se3,
    ext: Se3,
}

impl<
        K: Projector + Clone,
        const C: usize,
        const L: usize,
        const F: usize,
        const B: usize,
        const O: usize,
        const N: usize,
    > SchurProblem<RigParams<K, C, L, F, B>, N, B> for RigProblem<'_, C, L, F, B, O, N>
{
    fn normal_equations(
        &self,
        params: &RigParams<K, C, L, F, B>,
    ) -> Result<SchurSystem<N, B>, SolveError> {
        let mut ne = SchurSystem::new(self.priors.len(), self.prior_rows());
        self.add_measurements(params, &mut ne)?;
        self.for_each_prior(params, |k, r, j| ne.add_prior(k, r, j));
        ne.finite()
    }

    fn cost(&self, params: &RigParams<K, C, L, F, B>) -> Result<f64, SolveError> {
        RigProblem::cost(self, params)
    }

    fn apply(
        &self,
        params: &RigParams<K, C, L, F, B>,
        shared: &SVector<f64, N>,
        blocks: &[SVector<f64, 6>; B],
    ) -> RigParams<K, C, L, F, B> {
        apply_rig_step(params, shared, blocks)
    }

    fn structural_mask(&self, params: &RigParams<K, C, L, F, B>) -> [bool; N] {
        RigProblem::structural_mask(self, params)
    }
}

/// Levenberg–Marquardt ([`SETTINGS`]) on the rig problem from `params` (updated in place).
pub fn solve_rig<
    K: Projector + Clone,
    const C: usize,
    const L: usize,
    const F: usize,
    const B: usize,
    const O: usize,
    const N: usize,
>(
    problem: &RigProblem<'_, C, L, F, B, O, N>,
    params: &mut RigParams<K, C, L, F, B>,
    max_iterations: usize,
) -> Result<RigReport<C, L>, SolveError> {
    let (report, residuals) =
        schur::solve(problem, params, &SETTINGS.with_max_iterations(max_iterations))?;
    let (corner_rms_px, hole_rms_px) = problem.rms_px(params)?;
    Ok(RigReport {
        iterations: report.iterations,
        initial_cost: report.initial_cost,
        final_cost: report.final_cost,
        residuals,
        corner_rms_px,
        hole_rms_px,
    })
}

/// Covariance of the shared parameters at `params` (normally the solution), each
/// measurement kind (corners, holes, board faces and surveyed planes) scaled by its own
/// variance factor as the free-board covariance is ([`super::covariance::covariance`]);
/// the survey's priors keep their σ. Fixed parameters have zero rows and columns.
pub fn rig_covariance<
    K: Projector + Clone,
    const C: usize,
    const L: usize,
    const F: usize,
    const B: usize,
    const O: usize,
    const N: usize,
>(
    problem: &RigProblem<'_, C, L, F, B, O, N>,
    params: &RigParams<K, C, L, F, B>,
) -> Result<RigCovariance<N>, SolveError> {
    let matrix = kinds_covariance(
        problem,
        params,
        |each| {
            problem.for_each_residual(params, |k, kind, r, js, jb, rows| {
                each(k, kind, problem.loss_for(kind), r, js, jb, rows)
            })
        },
        |each| problem.for_each_prior(params, |k, r, j| each(k, r, j)),
    )?;
    Ok(RigCovariance { layout: RigProblem::<C, L, F, B, O, N>::LAYOUT, matrix })
}

/// `params ⊕ step`: additive intrinsics, left-perturbed mountings, room poses and blocks.
pub fn apply_rig_step<
    K: Projector + Clone,
    const C: usize,
    const L: usize,
    const F: usize,
    const B: usize,
    const N: usize,
>(
    params: &RigParams<K, C, L, F, B>,
    shared: &SVector<f64, N>,
    blocks: &[SVector<f64, 6>; B],
) -> RigParams<K, C, L, F, B> {
    let at = RigLayout { cameras: C, lidars: L, frames: F };
    let six = |i: usize| shared.fixed_rows::<6>(i).into_owned();
    let mut out = params.clone();
    for (c, camera) in out.cameras.iter_mut().enumerate() {
        let mut k = camera.params();
        for (i, v) in k.iter_mut().enumerate() {
            *v += shared[at.intrinsics(c) + i];
        }
        camera.set_params(&k);
    }
    for (c, pose) in out.first_to_camera.iter_mut().enumerate().skip(1) {
        *pose = pose.perturb_left(&six(at.camera_pose(c)));
    }
    for (l, pose) in out.lidar_to_first.iter_mut().enumerate() {
        *pose = pose.perturb_left(&six(at.lidar_pose(l)));
    }
    for (f, pose) in out.room_to_first.iter_mut().enumerate() {
        *pose = pose.perturb_left(&six(at.frame_pose(f)));
    }
    for (pose, d) in out.blocks.iter_mut().zip(blocks.iter()) {
        *pose = pose.perturb_left(d);
    }
    out
}

/// The map from the left perturbation of `T` to that of `T⁻¹`:
/// `δω' = −Rᵀ δω`, `δt' = −Rᵀ [t]× δω − Rᵀ δt`.
pub fn inverse_jacobian(pose: &Se3) -> SMatrix<f64, 6, 6> {
    let rt = pose.rotation.transpose();
    let mut j = SMatrix::<f64, 6, 6>::zeros();
    j.fixed_view_mut::<3, 3>(0, 0).copy_from(&(-rt));
    j.fixed_view_mut::<3, 3>(3, 0).copy_from(&(-rt * skew(&pose.translation)));
    j.fixed_view_mut::<3, 3>(3, 3).copy_from(&(-rt));
    j
}

impl<const N: usize> RigCovariance<N> {
    /// 1σ of camera `c`'s `[fx fy cx cy d0..d4]`.
    pub fn intrinsics_sigma(&self, c: usize) -> [f64; INTRINSICS] {
        let at = self.layout.intrinsics(c);
        core::array::from_fn(|i| libm::sqrt(self.matrix[(at + i, at + i)].max(0.0)))
    }

    /// Covariance of the left perturbation of camera `c` → first camera (`c ≥ 1`), from
    /// that of the solved first → `c` (`first_to_camera`).
    pub fn camera_to_first(&self, c: usize, first_to_camera: &Se3) -> SMatrix<f64, 6, 6> {
        let at = self.layout.camera_pose(c);
        let j = inverse_jacobian(first_to_camera);
        j * self.matrix.fixed_view::<6, 6>(at, at) * j.transpose()
    }

    /// Covariance of the left perturbation of LiDAR `l` → first camera.
    pub fn lidar_to_first(&self, l: usize) -> SMatrix<f64, 6, 6> {
        let at = self.layout.lidar_pose(l);
        self.matrix.fixed_view::<6, 6>(at, at).into_owned()
    }

    /// Covariance of camera `c`'s shared parameters as a one-pair run has them: its
    /// intrinsics, then LiDAR `l` → camera `c` (`[δω δt]`, zero without a LiDAR), with
    /// their cross terms, for the projection map.
    pub fn camera_shared(
        &self,
        c: usize,
        lidar: Option<(usize, &Se3, &Se3)>,
    ) -> SMatrix<f64, SHARED, SHARED> {
        let k = self.layout.intrinsics(c);
        let mut out = SMatrix::<f64, SHARED, SHARED>::zeros();
        let intrinsics = self.matrix.fixed_view::<INTRINSICS, INTRINSICS>(k, k);
        out.fixed_view_mut::<INTRINSICS, INTRINSICS>(0, 0).copy_from(&intrinsics);
        let Some((l, first_to_camera, lidar_to_first)) = lidar else { return out };
        let pose = self.lidar_to_camera(l, c, first_to_camera, lidar_to_first);
        // The pose's perturbation is `to_a δa + to_e δe` (`δe` alone for the first camera).
        let e = self.layout.lidar_pose(l);
        let mut cross = self.matrix.fixed_view::<INTRINSICS, 6>(k, e).into_owned();
        if c > 0 {
            let (to_a, to_e) = chain(first_to_camera, lidar_to_first);
            let a = self.layout.camera_pose(c);
            cross = self.matrix.fixed_view::<INTRINSICS, 6>(k, a) * to_a.transpose()
                + cross * to_e.transpose();
        }
        out.fixed_view_mut::<6, 6>(INTRINSICS, INTRINSICS).copy_from(&pose);
        out.fixed_view_mut::<INTRINSICS, 6>(0, INTRINSICS).copy_from(&cross);
        out.fixed_view_mut::<6, INTRINSICS>(INTRINSICS, 0).copy_from(&cross.transpose());
        out
    }

    /// Covariance of the left perturbation of LiDAR `l` → camera `c` = `A_c ∘ E_l`, from
    /// the solved first → `c` and LiDAR → first (their cross terms included).
    pub fn lidar_to_camera(
        &self,
        l: usize,
        c: usize,
        first_to_camera: &Se3,
        lidar_to_first: &Se3,
    ) -> SMatrix<f64, 6, 6> {
        if c == 0 {
            return self.lidar_to_first(l);
        }
        let (to_a, to_e) = chain(first_to_camera, lidar_to_first);
        let (a, e) = (self.layout.camera_pose(c), self.layout.lidar_pose(l));
        let block = |i: usize, j: usize| self.matrix.fixed_view::<6, 6>(i, j).into_owned();
        to_a * block(a, a) * to_a.transpose()
            + to_a * block(a, e) * to_e.transpose()
            + to_e * block(e, a) * to_a.transpose()
            + to_e * block(e, e) * to_e.transpose()
    }
}

/// Worst-axis 1σ of a pose covariance `[δω δt]`: rotation (rad) and translation (m).
pub fn worst_axis_sigma(covariance: &SMatrix<f64, 6, 6>) -> (f64, f64) {
    let worst = |at: usize| {
        let block = covariance.fixed_view::<3, 3>(at, at).into_owned();
        libm::sqrt(max_eigenvalue3(&block).max(0.0))
    };
    (worst(0), worst(3))
}

/// `cost`, or [`SolveError::NonFinite`] when it overflowed.
fn finite(cost: f64) -> Result<f64, SolveError> {
    if cost.is_finite() {
        Ok(cost)
    } else {
        Err(SolveError::NonFinite)
    }
}

/// The whitened prior residual `[log(R R₀ᵀ)/σ_r; (t − t₀)/σ_t]` of a block pose and its
/// Jacobian under the left perturbation (`J_l⁻¹` of the rotation error).
pub(crate) fn prior_residual(
    prior: &BlockPrior,
    pose: &Se3,
) -> (SVector<f64, 6>, SMatrix<f64, 6, 6>) {
    let (wr, wt) = (1.0 / prior.sigma_rad.max(PRIOR_FLOOR), 1.0 / prior.sigma_m.max(PRIOR_FLOOR));
    let phi = so3_log(&(pose.rotation * prior.pose.rotation.transpose()));
    let dt = pose.translation - prior.pose.translation;
    let r =
        SVector::<f64, 6>::new(phi.x * wr, phi.y * wr, phi.z * wr, dt.x * wt, dt.y * wt, dt.z * wt);
    let mut j = SMatrix::<f64, 6, 6>::zeros();
    j.fixed_view_mut::<3, 3>(0, 0).copy_from(&(so3_left_jacobian_inv(&phi) * wr));
    j.fixed_view_mut::<3, 3>(3, 3).copy_from(&(Mat3::identity() * wt));
    (r, j)
}

/// The maps from the left perturbations of `A` (e.g. room → camera) and `B` (block →
/// room) to that of `A ∘ B` (block → camera), see the module doc.
pub(crate) fn chain(a: &Se3, b: &Se3) -> (SMatrix<f64, 6, 6>, SMatrix<f64, 6, 6>) {
    let mut to_a = SMatrix::<f64, 6, 6>::identity();
    to_a.fixed_view_mut::<3, 3>(3, 0).copy_from(&(-skew(&(a.rotation * b.translation))));
    let mut to_b = SMatrix::<f64, 6, 6>::zeros();
    to_b.fixed_view_mut::<3, 3>(0, 0).copy_from(&a.rotation);
    to_b.fixed_view_mut::<3, 3>(3, 3).copy_from(&a.rotation);
    (to_a, to_b)
}
