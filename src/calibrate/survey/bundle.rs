//! The survey's bundle adjustment: one least-squares problem over every visit of a room.
//!
//! Unknowns: every room board's pose in the room frame (board 0 *is* the room frame, the
//! gauge, so it has none), every room plane (unit normal and offset), and per visit its
//! intrinsics, distortion, LiDAR→camera extrinsic and room→camera pose. Measurements:
//! corners, the paper's hole term and the board-face LiDAR points — exactly the free-board
//! terms of [`crate::solve::problem`], streamed through each visit's own
//! [`JointProblem`] with its board poses composed from the room's (`T_BC = T_RC · T_BR`)
//! — plus the LiDAR's points on the room planes (point to plane, summarised as
//! [`PlanePoints`]).
//!
//! Parameterisation (the solver's, see [`crate::solve`]): intrinsics additive, every rigid
//! motion left-perturbed (`R ← exp(δω) R`, `t ← t + δt`), a plane's normal turned by
//! `exp(B δφ)` with `B` two unit vectors across it, its offset additive. A visit's 21
//! parameters are `[intrinsics 9 | extrinsic δω δt | room→camera δω δt]`; the global ones
//! are `[board 1 δω δt | board 2 … | plane 0 δφ δd | plane 1 …]`.
//!
//! Sparse structure: a visit couples only to the boards and planes it sees, so the
//! normal equations are reduced with the Schur complement over the visits: per visit a
//! 21×21 block, its 21×G cross block and gradient; the reduced system is dense G×G
//! (G ≤ 15·6 + 16·3). All of it is allocated once before the solve ([`Workspace`]) and
//! nothing grows with the corners. The inverse of the reduced normal matrix is the
//! covariance of boards and planes with every visit marginalised.

use nalgebra::{DMatrix, DVector, SMatrix, SVector};

use crate::geometry::se3::{skew, so3_exp};
use crate::geometry::{Camera, Se3, Vec2, Vec3};
use crate::solve::linalg::Cholesky;
use crate::solve::minimize::{damp, damped, minimize, Problem, Settings};
use crate::solve::problem::ResidualKind;
use crate::solve::{
    BoardObservation, JointParams, JointProblem, Loss, ParamMask, PlanePoints, SolveError,
    EXT_ROTATION, INTRINSICS, SHARED,
};
use crate::target::{MAX_BOARDS, MAX_SURVEY_PLANES};

/// Most visits one survey solves.
pub const MAX_VISITS: usize = 64;
/// Parameters per visit: intrinsics, extrinsic, room→camera.
pub const VISIT: usize = SHARED + 6;
/// Index of the room→camera rotation in a visit's parameters.
pub const ROOM_ROTATION: usize = SHARED;
/// Most global parameters: every board but the gauge's, every plane.
pub const MAX_GLOBAL: usize = (MAX_BOARDS - 1) * 6 + MAX_SURVEY_PLANES * 3;

/// One board one visit saw, relabelled to its room board (corners and holes in the room
/// board's frame order).
#[derive(Clone, Debug, PartialEq)]
pub struct BundleBoard {
    pub room_board: usize,
    pub corners: Vec<Vec2>,
    /// The LiDAR's hole centres in the room's hole order (empty when it gave none).
    pub holes_lidar: Vec<Vec3>,
    /// The hole term's σ (px).
    pub hole_sigma_px: f64,
    /// The LiDAR's points on this board's face.
    pub plane: Option<PlanePoints>,
}

/// One visit's measurements for the bundle.
#[derive(Clone, Debug, PartialEq)]
pub struct BundleVisit {
    /// Corner σ (px).
    pub corner_sigma_px: f64,
    pub boards: Vec<BundleBoard>,
    /// `(room plane, the LiDAR's points on it)`.
    pub planes: Vec<(usize, PlanePoints)>,
}

/// One visit's unknowns.
#[derive(Clone, Debug, PartialEq)]
pub struct VisitState {
    pub camera: Camera,
    /// `p_camera = R p_lidar + t`.
    pub lidar_to_camera: Se3,
    /// `p_camera = R p_room + t`.
    pub room_to_camera: Se3,
}

/// A room plane: `normal · p_room = offset`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RoomPlane {
    pub normal: Vec3,
    pub offset: f64,
}

/// Everything the bundle estimates.
#[derive(Clone, Debug, PartialEq)]
pub struct SurveyState {
    pub visits: Vec<VisitState>,
    /// Board → room; `boards[0]` is the identity (the gauge).
    pub boards: Vec<Se3>,
    pub planes: Vec<RoomPlane>,
}

/// One whitened 2-row residual block and its Jacobians.
#[derive(Clone, Copy, Debug)]
pub struct Block {
    pub visit: usize,
    pub r: Vec2,
    /// `∂r/∂(visit parameters)`.
    pub j_visit: SMatrix<f64, 2, VISIT>,
    /// `(room board, ∂r/∂(its pose))`; `None` for board 0 and for room planes.
    pub board: Option<(usize, SMatrix<f64, 2, 6>)>,
    /// `(room plane, ∂r/∂[δφ δd])`.
    pub plane: Option<(usize, SMatrix<f64, 2, 3>)>,
    pub loss: Loss,
    /// Scalar measurements it stands for.
    pub rows: usize,
}

/// The survey's least-squares problem: the measurements by reference.
pub struct SurveyProblem<'a> {
    visits: Vec<VisitTerms<'a>>,
    boards: usize,
    planes: usize,
}

struct VisitTerms<'a> {
    problem: JointProblem<'a, MAX_BOARDS>,
    room_boards: heapless::Vec<usize, MAX_BOARDS>,
    planes: &'a [(usize, PlanePoints)],
}

/// What a bundle solve did.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BundleReport {
    pub iterations: usize,
    pub initial_cost: f64,
    pub final_cost: f64,
    /// Scalar measurements and free parameters.
    pub residuals: usize,
    pub parameters: usize,
}

/// 1σ of one board or plane (largest axis).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sigma {
    pub m: f64,
    pub deg: f64,
}

impl<'a> SurveyProblem<'a> {
    /// The problem over `visits`; `object` / `holes_board` are the board model's corners
    /// and holes (board frame). Fails when a capacity is exceeded or a board or plane
    /// index is out of range.
    pub fn new(
        object: &'a [Vec3],
        holes_board: &'a [Vec3],
        visits: &'a [BundleVisit],
        boards: usize,
        planes: usize,
    ) -> Result<Self, SolveError> {
        if visits.len() > MAX_VISITS || boards > MAX_BOARDS || planes > MAX_SURVEY_PLANES {
            return Err(SolveError::TooManyBoards { capacity: MAX_VISITS });
        }
        let mut terms = Vec::with_capacity(visits.len());
        for visit in visits {
            let mut problem = JointProblem::new(visit.corner_sigma_px, 1.0, Loss::Huber(3.0));
            let mut room_boards = heapless::Vec::new();
            for board in &visit.boards {
                if board.room_board >= boards {
                    return Err(SolveError::BadBoard {
                        board: board.room_board,
                        what: "no such room board",
                    });
                }
                let holes: &[Vec3] = if board.holes_lidar.is_empty() { &[] } else { holes_board };
                problem.add_board(BoardObservation {
                    object,
                    corners: &board.corners,
                    holes_board: holes,
                    holes_lidar: &board.holes_lidar,
                    hole_sigma_px: Some(board.hole_sigma_px),
                    plane: board.plane,
                })?;
                room_boards
                    .push(board.room_board)
                    .map_err(|_| SolveError::TooManyBoards { capacity: MAX_BOARDS })?;
            }
            if visit.planes.iter().any(|(p, _)| *p >= planes) {
                return Err(SolveError::Degenerate(
                    "a visit names a room plane that does not exist",
                ));
            }
            terms.push(VisitTerms { problem, room_boards, planes: &visit.planes });
        }
        Ok(SurveyProblem { visits: terms, boards, planes })
    }

    /// Global parameters: 6 per board but board 0, 3 per plane.
    pub fn global_len(&self) -> usize {
        6 * self.boards.saturating_sub(1) + 3 * self.planes
    }

    /// Column of room board `b`'s first parameter (`None` for the gauge board 0).
    pub fn board_column(&self, b: usize) -> Option<usize> {
        (b > 0).then(|| 6 * (b - 1))
    }

    /// Column of room plane `p`'s first parameter.
    pub fn plane_column(&self, p: usize) -> usize {
        6 * self.boards.saturating_sub(1) + 3 * p
    }

    /// Visit parameters no measurement can move: the camera model's unused intrinsics,
    /// and the extrinsic of a visit whose LiDAR gave nothing.
    pub fn visit_mask(&self, v: usize, state: &SurveyState) -> ParamMask {
        let terms = &self.visits[v];
        let camera = &state.visits[v].camera;
        let mask = ParamMask::free().fix_range(camera.num_params().min(INTRINSICS), INTRINSICS);
        let lidar = terms.problem.has_holes()
            || terms.problem.boards().iter().any(|b| b.plane.is_some())
            || !terms.planes.is_empty();
        if lidar {
            mask
        } else {
            mask.fix_extrinsic()
        }
    }

    /// Calls `f` with every whitened residual block and its Jacobians.
    pub fn for_each_block(
        &self,
        state: &SurveyState,
        mut f: impl FnMut(&Block),
    ) -> Result<(), SolveError> {
        for (v, terms) in self.visits.iter().enumerate() {
            let visit = &state.visits[v];
            let params = composed_params(terms, visit, &state.boards)?;
            let room = &visit.room_to_camera;
            terms.problem.for_each_residual(&params, |res| {
                let b = terms.room_boards[res.board];
                let t_b = state.boards[b].translation;
                let mut j_visit = SMatrix::<f64, 2, VISIT>::zeros();
                j_visit.fixed_view_mut::<2, SHARED>(0, 0).copy_from(&res.j_shared);
                j_visit
                    .fixed_view_mut::<2, 6>(0, ROOM_ROTATION)
                    .copy_from(&(res.j_board * room_chain(room, &t_b)));
                let board = (b > 0).then(|| (b, res.j_board * board_chain(room)));
                f(&Block {
                    visit: v,
                    r: res.r,
                    j_visit,
                    board,
                    plane: None,
                    loss: terms.problem.loss_for(res.kind),
                    rows: res.rows,
                });
            })?;
            for (p, points) in terms.planes {
                room_plane_blocks(v, *p, points, visit, &state.planes[*p], &mut f);
            }
        }
        Ok(())
    }

    /// Robust cost `½ Σ ρ(|r|²)`.
    pub fn cost(&self, state: &SurveyState) -> Result<f64, SolveError> {
        let mut cost = 0.0;
        self.for_each_block(state, |b| cost += 0.5 * b.loss.eval(b.r.norm_squared()).0)?;
        if cost.is_finite() {
            Ok(cost)
        } else {
            Err(SolveError::NonFinite)
        }
    }

    /// RMS pixel error of the corners over every visit (plain, no σ).
    pub fn corner_rms_px(&self, state: &SurveyState) -> Result<f64, SolveError> {
        let (mut sum, mut n) = (0.0, 0usize);
        for (v, terms) in self.visits.iter().enumerate() {
            let params = composed_params(terms, &state.visits[v], &state.boards)?;
            terms.problem.for_each_error(&params, |_, kind, e| {
                if matches!(kind, ResidualKind::Corner(_)) {
                    sum += e.norm_squared();
                    n += 1;
                }
            })?;
        }
        Ok(if n == 0 { 0.0 } else { (sum / n as f64).sqrt() })
    }
}

impl SurveyState {
    /// The state moved by `visit_steps` (one per visit) and `global` (the global vector).
    pub fn updated(
        &self,
        visit_steps: &[SVector<f64, VISIT>],
        global: &DVector<f64>,
    ) -> SurveyState {
        let mut out = self.clone();
        for (visit, step) in out.visits.iter_mut().zip(visit_steps) {
            let mut k = visit.camera.params();
            for (i, value) in k.iter_mut().enumerate() {
                *value += step[i];
            }
            visit.camera.set_params(&k);
            let ext = step.fixed_rows::<6>(EXT_ROTATION).into_owned();
            visit.lidar_to_camera = visit.lidar_to_camera.perturb_left(&ext);
            let room = step.fixed_rows::<6>(ROOM_ROTATION).into_owned();
            visit.room_to_camera = visit.room_to_camera.perturb_left(&room);
        }
        let nb = out.boards.len();
        for b in 1..nb {
            let d = global.fixed_rows::<6>(6 * (b - 1)).into_owned();
            out.boards[b] = out.boards[b].perturb_left(&d);
        }
        for (p, plane) in out.planes.iter_mut().enumerate() {
            let at = 6 * nb.saturating_sub(1) + 3 * p;
            let basis = tangent_basis(&plane.normal);
            let turn = basis * nalgebra::Vector2::new(global[at], global[at + 1]);
            plane.normal = (so3_exp(&turn) * plane.normal).normalize();
            plane.offset += global[at + 2];
        }
        out
    }
}

/// Two unit vectors across `n` (a fixed choice per `n`: the plane's update directions).
pub fn tangent_basis(n: &Vec3) -> SMatrix<f64, 3, 2> {
    let axis = if n.x.abs() <= n.y.abs() && n.x.abs() <= n.z.abs() {
        Vec3::x()
    } else if n.y.abs() <= n.z.abs() {
        Vec3::y()
    } else {
        Vec3::z()
    };
    let b1 = n.cross(&axis).normalize();
    let b2 = n.cross(&b1);
    SMatrix::<f64, 3, 2>::from_columns(&[b1, b2])
}

/// The normal equations and the Schur workspace, allocated once per solve.
pub struct Workspace {
    global: usize,
    /// Per visit: `JᵀWJ` (21×21), cross block (21×G), gradient; and its mask.
    hvv: Vec<SMatrix<f64, VISIT, VISIT>>,
    hvg: Vec<DMatrix<f64>>,
    gv: Vec<SVector<f64, VISIT>>,
    masks: Vec<ParamMask>,
    hgg: DMatrix<f64>,
    gg: DVector<f64>,
    /// Reduced system and its right-hand side, a 21×G scratch.
    s: DMatrix<f64>,
    rhs: DVector<f64>,
    y: DMatrix<f64>,
    cost: f64,
    residuals: usize,
}

impl Workspace {
    /// A workspace for `problem` (every buffer at its final size).
    pub fn new(problem: &SurveyProblem<'_>) -> Workspace {
        let (n, g) = (problem.visits.len(), problem.global_len());
        Workspace {
            global: g,
            hvv: vec![SMatrix::zeros(); n],
            hvg: vec![DMatrix::zeros(VISIT, g); n],
            gv: vec![SVector::zeros(); n],
            masks: vec![ParamMask::free(); n],
            hgg: DMatrix::zeros(g, g),
            gg: DVector::zeros(g),
            s: DMatrix::zeros(g, g),
            rhs: DVector::zeros(g),
            y: DMatrix::zeros(VISIT, g),
            cost: 0.0,
            residuals: 0,
        }
    }

    /// Accumulates the (undamped) normal equations at `state`.
    pub fn build(
        &mut self,
        problem: &SurveyProblem<'_>,
        state: &SurveyState,
    ) -> Result<(), SolveError> {
        for v in 0..self.hvv.len() {
            self.hvv[v].fill(0.0);
            self.hvg[v].fill(0.0);
            self.gv[v].fill(0.0);
            self.masks[v] = problem.visit_mask(v, state);
        }
        self.hgg.fill(0.0);
        self.gg.fill(0.0);
        self.cost = 0.0;
        self.residuals = 0;
        problem.for_each_block(state, |blk| self.accumulate(problem, blk))?;
        for v in 0..self.hvv.len() {
            let mask = self.masks[v];
            for i in 0..VISIT {
                let unmoved = self.hvv[v][(i, i)] <= 0.0;
                if (i < SHARED && mask.is_fixed(i)) || unmoved {
                    self.hvv[v].row_mut(i).fill(0.0);
                    self.hvv[v].column_mut(i).fill(0.0);
                    self.hvv[v][(i, i)] = 1.0;
                    self.hvg[v].row_mut(i).fill(0.0);
                    self.gv[v][i] = 0.0;
                }
            }
        }
        if self.cost.is_finite() {
            Ok(())
        } else {
            Err(SolveError::NonFinite)
        }
    }

    /// Adds one block to the normal equations.
    fn accumulate(&mut self, problem: &SurveyProblem<'_>, blk: &Block) {
        let (rho, w) = blk.loss.eval(blk.r.norm_squared());
        self.cost += 0.5 * rho;
        self.residuals += blk.rows;
        let v = blk.visit;
        self.hvv[v].gemm_tr(w, &blk.j_visit, &blk.j_visit, 1.0);
        self.gv[v].gemv_tr(w, &blk.j_visit, &blk.r, 1.0);
        if let Some((b, j)) = &blk.board {
            let col = problem.board_column(*b).expect("board 0 has no global block");
            self.add_global(v, col, blk, j, w);
        }
        if let Some((p, j)) = &blk.plane {
            self.add_global(v, problem.plane_column(*p), blk, j, w);
        }
    }

    /// The terms of a block's global Jacobian `j` (columns `col..col + K`). A block
    /// touches one board or one plane, so only that diagonal block of `H_gg` grows.
    fn add_global<const K: usize>(
        &mut self,
        v: usize,
        col: usize,
        blk: &Block,
        j: &SMatrix<f64, 2, K>,
        w: f64,
    ) {
        let cross: SMatrix<f64, VISIT, K> = blk.j_visit.transpose() * j * w;
        let jj: SMatrix<f64, K, K> = j.transpose() * j * w;
        let gr: SVector<f64, K> = j.transpose() * blk.r * w;
        for c in 0..K {
            for i in 0..VISIT {
                self.hvg[v][(i, col + c)] += cross[(i, c)];
            }
            for i in 0..K {
                self.hgg[(col + i, col + c)] += jj[(i, c)];
            }
            self.gg[col + c] += gr[c];
        }
    }

    /// Reduces the damped system over the visits into `self.s`, `self.rhs`
    /// (`S δg = rhs`).
    fn reduce(&mut self, lambda: f64) -> Result<(), SolveError> {
        self.s.copy_from(&self.hgg);
        damp(&mut self.s, lambda);
        for i in 0..self.global {
            self.rhs[i] = -self.gg[i];
        }
        for v in 0..self.hvv.len() {
            let ch = Cholesky::new(&damped(&self.hvv[v], lambda))?;
            // Y = H_vv⁻¹ H_vg, column by column.
            for c in 0..self.global {
                let col =
                    SVector::<f64, VISIT>::from_iterator(self.hvg[v].column(c).iter().copied());
                self.y.set_column(c, &ch.solve(&col));
            }
            self.s.gemm_tr(-1.0, &self.hvg[v], &self.y, 1.0);
            // rhs −= −H_gv H_vv⁻¹ g_v  ⇒  rhs += Yᵀ g_v.
            self.rhs.gemv_tr(1.0, &self.y, &self.gv[v], 1.0);
        }
        Ok(())
    }

    /// The damped step: per visit and global.
    fn step(
        &mut self,
        lambda: f64,
        visit_steps: &mut [SVector<f64, VISIT>],
        global: &mut DVector<f64>,
    ) -> Result<(), SolveError> {
        self.reduce(lambda)?;
        global.copy_from(&self.rhs);
        cholesky_solve_in_place(&mut self.s, global)?;
        for (v, out) in visit_steps.iter_mut().enumerate().take(self.hvv.len()) {
            let ch = Cholesky::new(&damped(&self.hvv[v], lambda))?;
            let mut rhs = -self.gv[v];
            for (c, g) in global.iter().enumerate() {
                if *g != 0.0 {
                    for i in 0..VISIT {
                        rhs[i] -= self.hvg[v][(i, c)] * g;
                    }
                }
            }
            *out = ch.solve(&rhs);
        }
        Ok(())
    }

    /// Covariance of the global parameters (the inverse of the undamped reduced system).
    pub fn global_covariance(&mut self) -> Result<DMatrix<f64>, SolveError> {
        self.reduce(0.0)?;
        let g = self.global;
        let mut inverse = DMatrix::<f64>::identity(g, g);
        let mut s = self.s.clone();
        cholesky_factor_in_place(&mut s)?;
        for c in 0..g {
            let mut col = inverse.column(c).into_owned();
            cholesky_solve_factored(&s, &mut col);
            inverse.set_column(c, &col);
        }
        Ok(inverse)
    }
}

/// How the bundle is solved: Marquardt's schedule; stop when an accepted step lowers the
/// cost by at most 10⁻¹⁰ of it, the tolerance the survey results were validated with (a
/// survey is solved once per room, and its boards are every later calibration's target).
/// No gradient or step test.
pub const SETTINGS: Settings = Settings { cost_tolerance: 1e-10, ..Settings::MARQUARDT };

/// Runs Levenberg–Marquardt ([`SETTINGS`] with `max_iterations`) from `state` (updated in
/// place to the best estimate found).
pub fn solve(
    problem: &SurveyProblem<'_>,
    state: &mut SurveyState,
    max_iterations: usize,
) -> Result<BundleReport, SolveError> {
    let mut bundle = Bundle {
        problem,
        ws: Workspace::new(problem),
        visit_steps: vec![SVector::<f64, VISIT>::zeros(); problem.visits.len()],
        global: DVector::<f64>::zeros(problem.global_len()),
    };
    let report = minimize(&mut bundle, state, &SETTINGS.with_max_iterations(max_iterations))?;
    let ws = &bundle.ws;
    let parameters =
        ws.masks.iter().map(|m| m.free_count() + 6).sum::<usize>() + problem.global_len();
    Ok(BundleReport {
        iterations: report.iterations,
        initial_cost: report.initial_cost,
        final_cost: report.final_cost,
        residuals: ws.residuals,
        parameters,
    })
}

/// The bundle as [`minimize`] drives it: the workspace and the step, allocated once.
struct Bundle<'p, 'a> {
    problem: &'p SurveyProblem<'a>,
    ws: Workspace,
    visit_steps: Vec<SVector<f64, VISIT>>,
    global: DVector<f64>,
}

impl Problem for Bundle<'_, '_> {
    type Params = SurveyState;

    fn linearize(&mut self, state: &SurveyState) -> Result<f64, SolveError> {
        self.ws.build(self.problem, state)?;
        Ok(self.ws.cost)
    }

    fn solve_step(&mut self, lambda: f64) -> Result<(), SolveError> {
        self.ws.step(lambda, &mut self.visit_steps, &mut self.global)
    }

    fn apply(&self, state: &SurveyState) -> SurveyState {
        state.updated(&self.visit_steps, &self.global)
    }

    fn cost(&self, state: &SurveyState) -> Result<f64, SolveError> {
        self.problem.cost(state)
    }
}

/// A visit's free-board parameters with its board poses composed from the room's.
fn composed_params(
    terms: &VisitTerms<'_>,
    visit: &VisitState,
    boards: &[Se3],
) -> Result<JointParams<Camera, MAX_BOARDS>, SolveError> {
    let mut poses = heapless::Vec::new();
    for &b in &terms.room_boards {
        poses
            .push(visit.room_to_camera.compose(&boards[b]))
            .map_err(|_| SolveError::TooManyBoards { capacity: MAX_BOARDS })?;
    }
    Ok(JointParams {
        camera: visit.camera,
        lidar_to_camera: visit.lidar_to_camera,
        board_poses: poses,
    })
}

/// `∂(T_RC · T_BR)/∂(T_RC)` in left perturbations: `[[I, 0], [−[R_RC t_B]×, I]]`.
fn room_chain(room: &Se3, board_translation: &Vec3) -> SMatrix<f64, 6, 6> {
    let mut m = SMatrix::<f64, 6, 6>::identity();
    m.fixed_view_mut::<3, 3>(3, 0).copy_from(&(-skew(&(room.rotation * board_translation))));
    m
}

/// `∂(T_RC · T_BR)/∂(T_BR)` in left perturbations: `diag(R_RC, R_RC)`.
fn board_chain(room: &Se3) -> SMatrix<f64, 6, 6> {
    let mut m = SMatrix::<f64, 6, 6>::zeros();
    m.fixed_view_mut::<3, 3>(0, 0).copy_from(&room.rotation);
    m.fixed_view_mut::<3, 3>(3, 3).copy_from(&room.rotation);
    m
}

/// The two whitened 2-row blocks of one visit's points on one room plane.
///
/// With `n_c = R_RC n` (the plane's normal in the camera), `q = R_LC c + t_LC` (the
/// points' centroid in the camera), the residual is `G [a; b] / σ` with
/// `a = R_LCᵀ n_c` (the normal in the LiDAR frame), `b = n_c · (q − t_RC) − offset`, and
/// `G = diag(Lᵀ, √W)` as in [`PlanePoints`]. Under the left perturbations:
/// - extrinsic: `δa = R_LCᵀ [n_c]× δω`, `δb = (R_LC c × n_c)ᵀ δω + n_cᵀ δt`;
/// - room→camera: `δa = −R_LCᵀ [n_c]× δω`, `δb = (n_c × (q − t_RC))ᵀ δω − n_cᵀ δt`;
/// - plane: `δn = −[n]× B δφ`, so `δa = R_LCᵀ R_RC δn`, `δb = (q − t_RC)ᵀ R_RC δn − δd`.
fn room_plane_blocks(
    visit: usize,
    plane: usize,
    points: &PlanePoints,
    state: &VisitState,
    room_plane: &RoomPlane,
    f: &mut impl FnMut(&Block),
) {
    let (ext, room) = (&state.lidar_to_camera, &state.room_to_camera);
    let n = room_plane.normal;
    let n_c = room.rotation * n;
    let q = ext.rotation * points.centroid + ext.translation;
    let m = q - room.translation;
    let a = ext.rotation.transpose() * n_c;
    let b = n_c.dot(&m) - room_plane.offset;
    let rt_ncx = ext.rotation.transpose() * skew(&n_c);
    // ∂[a; b]/∂[extrinsic δω δt | room δω δt | plane δφ δd] (4×15).
    let mut dw = SMatrix::<f64, 4, 15>::zeros();
    dw.fixed_view_mut::<3, 3>(0, 0).copy_from(&rt_ncx);
    dw.fixed_view_mut::<1, 3>(3, 0)
        .copy_from(&(ext.rotation * points.centroid).cross(&n_c).transpose());
    dw.fixed_view_mut::<1, 3>(3, 3).copy_from(&n_c.transpose());
    dw.fixed_view_mut::<3, 3>(0, 6).copy_from(&(-rt_ncx));
    dw.fixed_view_mut::<1, 3>(3, 6).copy_from(&n_c.cross(&m).transpose());
    dw.fixed_view_mut::<1, 3>(3, 9).copy_from(&(-n_c.transpose()));
    let dn = -skew(&n) * tangent_basis(&n);
    dw.fixed_view_mut::<3, 2>(0, 12).copy_from(&(ext.rotation.transpose() * room.rotation * dn));
    dw.fixed_view_mut::<1, 2>(3, 12).copy_from(&(m.transpose() * room.rotation * dn));
    dw[(3, 14)] = -1.0;
    let mut g = SMatrix::<f64, 4, 4>::zeros();
    g.fixed_view_mut::<3, 3>(0, 0).copy_from(&points.spread);
    let root = points.root_weight();
    g[(3, 3)] = root;
    let w = 1.0 / points.sigma_m;
    let top = points.spread * a;
    let r = nalgebra::Vector4::new(top.x, top.y, top.z, root * b) * w;
    let j = g * dw * w;
    let half = points.count / 2;
    for k in 0..2 {
        let mut j_visit = SMatrix::<f64, 2, VISIT>::zeros();
        j_visit.fixed_view_mut::<2, 6>(0, EXT_ROTATION).copy_from(&j.fixed_view::<2, 6>(2 * k, 0));
        j_visit.fixed_view_mut::<2, 6>(0, ROOM_ROTATION).copy_from(&j.fixed_view::<2, 6>(2 * k, 6));
        f(&Block {
            visit,
            r: Vec2::new(r[2 * k], r[2 * k + 1]),
            j_visit,
            board: None,
            plane: Some((plane, j.fixed_view::<2, 3>(2 * k, 12).into_owned())),
            loss: Loss::Squared,
            rows: if k == 0 { points.count - half } else { half },
        });
    }
}

/// Lower Cholesky factor of a symmetric positive-definite matrix, in place (the upper
/// triangle is left as it was and never read).
fn cholesky_factor_in_place(a: &mut DMatrix<f64>) -> Result<(), SolveError> {
    let n = a.nrows();
    for j in 0..n {
        let mut d = a[(j, j)];
        for k in 0..j {
            d -= a[(j, k)] * a[(j, k)];
        }
        if !(d > 0.0 && d.is_finite()) {
            return Err(SolveError::NotPositiveDefinite { pivot: j });
        }
        let d = d.sqrt();
        a[(j, j)] = d;
        for i in j + 1..n {
            let mut s = a[(i, j)];
            for k in 0..j {
                s -= a[(i, k)] * a[(j, k)];
            }
            a[(i, j)] = s / d;
        }
    }
    Ok(())
}

/// `x ← A⁻¹ x` with `A`'s lower Cholesky factor in `l`.
fn cholesky_solve_factored(l: &DMatrix<f64>, x: &mut DVector<f64>) {
    let n = l.nrows();
    for i in 0..n {
        let mut s = x[i];
        for k in 0..i {
            s -= l[(i, k)] * x[k];
        }
        x[i] = s / l[(i, i)];
    }
    for i in (0..n).rev() {
        let mut s = x[i];
        for k in i + 1..n {
            s -= l[(k, i)] * x[k];
        }
        x[i] = s / l[(i, i)];
    }
}

/// `x ← A⁻¹ x`, factorising `a` in place.
fn cholesky_solve_in_place(a: &mut DMatrix<f64>, x: &mut DVector<f64>) -> Result<(), SolveError> {
    cholesky_factor_in_place(a)?;
    cholesky_solve_factored(a, x);
    Ok(())
}
