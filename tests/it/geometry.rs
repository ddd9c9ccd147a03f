//! Tests of the geometry core: SO(3)/SE(3) maps and every analytic Jacobian against
//! central differences, camera round trips over whole images, the inversion domain, and
//! agreement with OpenCV (tests/data/opencv_projections.json, made by
//! scripts/opencv_projections.py). Run with `--nocapture` to see the measured figures.

use nalgebra::{Matrix4, SMatrix};
use roomcal::geometry::camera::{FISHEYE_MAX_THETA, MAX_INTRINSICS};
use roomcal::geometry::se3::{
    act_jacobian_local, act_jacobian_rvec, quaternion_to_rotation, rotation_to_quaternion,
    rotation_to_rpy, rpy_to_rotation, skew, so3_exp, so3_left_jacobian, so3_left_jacobian_inv,
    so3_log, so3_right_jacobian, so3_right_jacobian_inv,
};
use roomcal::geometry::{Camera, CameraModel, Mat3, Se3, Vec2, Vec3, Vec6};
use std::f64::consts::PI;

/// splitmix64: a tiny deterministic generator so failures reproduce.
struct Rng(u64);

impl Rng {
    fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    fn uniform(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * ((self.next_u64() >> 11) as f64 / (1u64 << 53) as f64)
    }
    fn unit_vec(&mut self) -> Vec3 {
        loop {
            let v = Vec3::new(
                self.uniform(-1.0, 1.0),
                self.uniform(-1.0, 1.0),
                self.uniform(-1.0, 1.0),
            );
            let n = v.norm();
            if n > 0.1 && n <= 1.0 {
                return v / n;
            }
        }
    }
    fn rvec(&mut self, max_angle: f64) -> Vec3 {
        self.unit_vec() * self.uniform(0.0, max_angle)
    }
}

/// Largest entry-wise error, scaled by max(1, |reference entry|).
fn scaled_err<const R: usize, const C: usize>(
    a: &SMatrix<f64, R, C>,
    reference: &SMatrix<f64, R, C>,
) -> f64 {
    a.iter()
        .zip(reference.iter())
        .map(|(x, y)| (x - y).abs() / y.abs().max(1.0))
        .fold(0.0, f64::max)
}

/// Central-difference Jacobian of `f: ℝ^N → ℝ^M` at `x` with per-coordinate steps.
fn numeric_jacobian<const M: usize, const N: usize>(
    f: impl Fn(&SMatrix<f64, N, 1>) -> SMatrix<f64, M, 1>,
    x: &SMatrix<f64, N, 1>,
    steps: &SMatrix<f64, N, 1>,
) -> SMatrix<f64, M, N> {
    let mut j = SMatrix::<f64, M, N>::zeros();
    for i in 0..N {
        let mut xp = *x;
        let mut xm = *x;
        xp[i] += steps[i];
        xm[i] -= steps[i];
        j.set_column(i, &((f(&xp) - f(&xm)) / (xp[i] - xm[i])));
    }
    j
}

fn is_rotation(r: &Mat3) -> bool {
    (r.transpose() * r - Mat3::identity()).norm() < 1e-12 && (r.determinant() - 1.0).abs() < 1e-12
}

// ---------------------------------------------------------------- SO(3) / SE(3)

#[test]
fn so3_exp_log_round_trip_including_zero_and_pi() {
    let mut rng = Rng(1);
    let mut angles: Vec<f64> = vec![0.0, 1e-300, 1e-12, 1e-8, 1e-5, 1e-4, 0.5, PI / 2.0];
    angles.extend([PI - 1e-3, PI - 1e-6, PI - 1e-9, PI - 1e-12]);
    for _ in 0..2000 {
        angles.push(rng.uniform(0.0, PI));
    }
    let mut worst = 0.0f64;
    for &a in &angles {
        let w = rng.unit_vec() * a;
        let r = so3_exp(&w);
        assert!(is_rotation(&r), "exp({w:?}) not a rotation");
        let back = so3_log(&r);
        // Near π the rotation only fixes the axis up to sign.
        let err = if a > PI - 1e-6 {
            (back - w).norm().min((back + w).norm())
        } else {
            (back - w).norm()
        };
        worst = worst.max(err / a.clamp(f64::EPSILON, 1.0));
        assert!(err <= 1e-12 * a.max(1e-3) + 1e-15, "log(exp(w)) error {err:e} at |w| = {a}");
        assert!((so3_exp(&back) - r).norm() < 1e-14, "exp(log(R)) != R at |w| = {a}");
    }
    // Exactly π about every principal and a diagonal axis.
    for axis in [Vec3::x(), Vec3::y(), Vec3::z(), Vec3::new(1.0, 1.0, 1.0).normalize()] {
        let r = so3_exp(&(axis * PI));
        let w = so3_log(&r);
        assert!((w.norm() - PI).abs() < 1e-12 && (so3_exp(&w) - r).norm() < 1e-14);
    }
    println!("so3 log∘exp worst (relative) error: {worst:.2e}");
}

#[test]
fn so3_exp_small_angle_matches_series_and_skew_is_cross() {
    let mut rng = Rng(2);
    for _ in 0..100 {
        let (a, b) = (rng.unit_vec(), rng.unit_vec());
        assert!((skew(&a) * b - a.cross(&b)).norm() < 1e-15);
        let w = a * 1e-5;
        let k = skew(&w);
        let series = Mat3::identity() + k + k * k * 0.5 + k * k * k / 6.0;
        assert!((so3_exp(&w) - series).norm() < 1e-18);
    }
}

#[test]
fn so3_jacobians_match_central_differences() {
    let mut rng = Rng(3);
    let (mut worst_l, mut worst_r, mut worst_inv) = (0.0f64, 0.0f64, 0.0f64);
    let mut angles = vec![0.0, 1e-7, 1e-3];
    for _ in 0..500 {
        angles.push(rng.uniform(0.0, 3.0));
    }
    for &a in &angles {
        let w = rng.unit_vec() * a;
        let r0 = so3_exp(&w);
        let h = Vec3::repeat(1e-6);
        // exp(w + δ) = exp(J_l δ) exp(w)  ⇒  J_l = ∂ log(exp(w + δ) exp(w)ᵀ) / ∂δ.
        let jl_num = numeric_jacobian(
            |d| so3_log(&(so3_exp(&(w + d)) * r0.transpose())),
            &Vec3::zeros(),
            &h,
        );
        let jr_num = numeric_jacobian(
            |d| so3_log(&(r0.transpose() * so3_exp(&(w + d)))),
            &Vec3::zeros(),
            &h,
        );
        // log(exp(δ) exp(w)) ≈ w + J_l⁻¹ δ, and on the right with J_r⁻¹.
        let jli_num = numeric_jacobian(|d| so3_log(&(so3_exp(d) * r0)), &Vec3::zeros(), &h);
        let jri_num = numeric_jacobian(|d| so3_log(&(r0 * so3_exp(d))), &Vec3::zeros(), &h);
        worst_inv = worst_inv.max(scaled_err(&so3_left_jacobian_inv(&w), &jli_num));
        worst_inv = worst_inv.max(scaled_err(&so3_right_jacobian_inv(&w), &jri_num));
        let (jl, jr) = (so3_left_jacobian(&w), so3_right_jacobian(&w));
        worst_l = worst_l.max(scaled_err(&jl, &jl_num));
        worst_r = worst_r.max(scaled_err(&jr, &jr_num));
        assert!((so3_left_jacobian_inv(&w) * jl - Mat3::identity()).norm() < 1e-12);
        assert!((so3_right_jacobian_inv(&w) * jr - Mat3::identity()).norm() < 1e-12);
        assert!((jr - jl.transpose()).norm() < 1e-15);
    }
    println!("so3 J_l worst error {worst_l:.2e}, J_r {worst_r:.2e}, inverses {worst_inv:.2e}");
    assert!(worst_l < 1e-8 && worst_r < 1e-8 && worst_inv < 1e-8);
}

#[test]
fn point_action_jacobians_match_central_differences() {
    let mut rng = Rng(4);
    let (mut worst_rvec, mut worst_local) = (0.0f64, 0.0f64);
    for i in 0..1000 {
        let w = if i < 10 { rng.unit_vec() * 1e-9 } else { rng.rvec(3.1) };
        let p = rng.unit_vec() * rng.uniform(0.1, 20.0);
        let t = rng.unit_vec() * rng.uniform(0.0, 5.0);
        let num = numeric_jacobian(|w| so3_exp(w) * p, &w, &Vec3::repeat(1e-6));
        let ana = act_jacobian_rvec(&w, &p);
        worst_rvec = worst_rvec.max(scaled_err(&ana, &num));
        let r = so3_exp(&w);
        let num = numeric_jacobian(|d| so3_exp(d) * r * p + t, &Vec3::zeros(), &Vec3::repeat(1e-6));
        worst_local = worst_local.max(scaled_err(&act_jacobian_local(&r, &p), &num));
        // perturb_left is the motion whose point Jacobian act_jacobian_local is.
        let pose = Se3 { rotation: r, translation: t };
        let num6 =
            numeric_jacobian(|d| pose.perturb_left(d).act(&p), &Vec6::zeros(), &Vec6::repeat(1e-6));
        let mut ana6 = SMatrix::<f64, 3, 6>::zeros();
        ana6.fixed_view_mut::<3, 3>(0, 0).copy_from(&act_jacobian_local(&r, &p));
        ana6.fixed_view_mut::<3, 3>(0, 3).copy_from(&Mat3::identity());
        worst_local = worst_local.max(scaled_err(&ana6, &num6));
    }
    println!("act Jacobian worst error: rvec {worst_rvec:.2e}, local {worst_local:.2e}");
    assert!(worst_rvec < 1e-7 && worst_local < 1e-7);
}

#[test]
fn se3_exp_log_compose_inverse_quaternion() {
    let mut rng = Rng(5);
    for i in 0..500 {
        let w = if i < 5 { rng.unit_vec() * 1e-10 } else { rng.rvec(3.1) };
        let rho = rng.unit_vec() * rng.uniform(0.0, 3.0);
        let xi = Vec6::new(w.x, w.y, w.z, rho.x, rho.y, rho.z);
        let t = Se3::exp(&xi);
        // Against the 4×4 matrix exponential of the twist.
        let mut m = Matrix4::<f64>::zeros();
        m.fixed_view_mut::<3, 3>(0, 0).copy_from(&skew(&w));
        m.fixed_view_mut::<3, 1>(0, 3).copy_from(&rho);
        let e = m.exp();
        assert!((e.fixed_view::<3, 3>(0, 0) - t.rotation).norm() < 1e-12);
        assert!((e.fixed_view::<3, 1>(0, 3) - t.translation).norm() < 1e-12);
        assert!((t.log() - xi).norm() < 1e-11, "log(exp(xi)) != xi");

        let a = Se3::from_rvec_t(&rng.rvec(3.0), &rng.unit_vec());
        let p = rng.unit_vec() * 3.0;
        assert!((a.compose(&t).act(&p) - a.act(&t.act(&p))).norm() < 1e-12);
        assert!((a.inverse().act(&a.act(&p)) - p).norm() < 1e-12);
        assert!((a.compose(&a.inverse()).rotation - Mat3::identity()).norm() < 1e-14);
        assert!((so3_exp(&a.rvec()) - a.rotation).norm() < 1e-13);

        let q = a.to_quaternion();
        assert!(q[0] >= 0.0 && (q.iter().map(|v| v * v).sum::<f64>() - 1.0).abs() < 1e-14);
        let b = Se3::from_quaternion(&q, &a.translation).unwrap();
        assert!((b.rotation - a.rotation).norm() < 1e-14);
        // q and −q are the same rotation.
        let nq = [-q[0] * 2.0, -q[1] * 2.0, -q[2] * 2.0, -q[3] * 2.0];
        assert!((quaternion_to_rotation(&nq).unwrap() - a.rotation).norm() < 1e-14);
        // The quaternion's vector part is sin(θ/2)·axis.
        let rv = a.rvec();
        let half = 0.5 * rv.norm();
        let expected = rv.normalize() * half.sin();
        let qv = Vec3::new(q[1], q[2], q[3]);
        assert!((qv - expected).norm() < 1e-12 || (qv + expected).norm() < 1e-12);
    }
    // 90° about z.
    let q = rotation_to_quaternion(&so3_exp(&Vec3::new(0.0, 0.0, PI / 2.0)));
    let s = 0.5f64.sqrt();
    assert!(
        (q[0] - s).abs() < 1e-15
            && q[1].abs() < 1e-15
            && q[2].abs() < 1e-15
            && (q[3] - s).abs() < 1e-15
    );
    assert!(quaternion_to_rotation(&[0.0; 4]).is_none());
    assert!(quaternion_to_rotation(&[f64::NAN, 0.0, 0.0, 1.0]).is_none());
}

#[test]
fn roll_pitch_yaw_round_trip_and_follow_urdf_order() {
    // URDF: R = Rz(yaw) · Ry(pitch) · Rx(roll), each a rotation about a fixed axis.
    let (roll, pitch, yaw) = (0.3, -0.4, 1.2);
    let about = |axis: Vec3, angle: f64| so3_exp(&(axis * angle));
    let urdf = about(Vec3::z(), yaw) * about(Vec3::y(), pitch) * about(Vec3::x(), roll);
    assert!((rpy_to_rotation(&[roll, pitch, yaw]) - urdf).norm() < 1e-15);
    let [r, p, y] = rotation_to_rpy(&urdf);
    assert!((r - roll).abs() < 1e-14 && (p - pitch).abs() < 1e-14 && (y - yaw).abs() < 1e-14);
    let mut rng = Rng(11);
    for _ in 0..500 {
        let rotation = so3_exp(&rng.rvec(3.1));
        let rpy = rotation_to_rpy(&rotation);
        assert!(rpy[1].abs() <= PI / 2.0 && rpy[0].abs() <= PI && rpy[2].abs() <= PI);
        assert!((rpy_to_rotation(&rpy) - rotation).norm() < 1e-12, "{rpy:?}");
    }
    // Gimbal lock: pitch ±90° still gives back the rotation.
    for pitch in [PI / 2.0, -PI / 2.0] {
        let locked = about(Vec3::z(), 0.7) * about(Vec3::y(), pitch) * about(Vec3::x(), 0.2);
        assert!((rpy_to_rotation(&rotation_to_rpy(&locked)) - locked).norm() < 1e-12);
    }
}

// ---------------------------------------------------------------- cameras

fn radtan(w: u32, h: u32, hfov: f64, d: [f64; 5]) -> Camera {
    Camera::try_from_fov(CameraModel::PinholeRadtan, w, h, hfov, d).expect("valid radtan camera")
}

fn fisheye(w: u32, h: u32, hfov: f64, k: [f64; 4]) -> Camera {
    Camera::try_from_fov(CameraModel::Fisheye, w, h, hfov, [k[0], k[1], k[2], k[3], 0.0])
        .expect("valid fisheye camera")
}

/// A random camera of either model with moderate, monotonic-enough distortion.
fn random_camera(rng: &mut Rng, model: CameraModel) -> Camera {
    let (fx, fy) = (rng.uniform(300.0, 1500.0), rng.uniform(300.0, 1500.0));
    let (cx, cy) = (rng.uniform(500.0, 1400.0), rng.uniform(300.0, 900.0));
    let distortion = match model {
        CameraModel::PinholeRadtan => [
            rng.uniform(-0.4, 0.4),
            rng.uniform(-0.1, 0.2),
            rng.uniform(-2e-3, 2e-3),
            rng.uniform(-2e-3, 2e-3),
            rng.uniform(-0.05, 0.05),
        ],
        CameraModel::Fisheye => [
            rng.uniform(-0.05, 0.1),
            rng.uniform(-0.05, 0.05),
            rng.uniform(-0.02, 0.02),
            rng.uniform(-0.01, 0.01),
            0.0,
        ],
    };
    Camera { model, width: 1920, height: 1200, fx, fy, cx, cy, distortion }
}

/// A random point in the camera's domain, up to `frac` of the way to its edge.
fn random_point_in_domain(rng: &mut Rng, cam: &Camera, frac: f64) -> Vec3 {
    let phi = rng.uniform(0.0, 2.0 * PI);
    let dist = rng.uniform(0.3, 30.0);
    let theta = match cam.model {
        CameraModel::PinholeRadtan => {
            let r_lim = (cam.max_valid_radius() * frac).min(3.0);
            (r_lim * rng.uniform(0.0, 1.0).sqrt()).atan()
        }
        CameraModel::Fisheye => cam.max_valid_radius() * frac * rng.uniform(0.0, 1.0).sqrt(),
    };
    Vec3::new(theta.sin() * phi.cos(), theta.sin() * phi.sin(), theta.cos()) * dist
}

#[test]
fn camera_jacobians_match_central_differences() {
    let mut rng = Rng(6);
    for model in [CameraModel::PinholeRadtan, CameraModel::Fisheye] {
        let (mut worst_p, mut worst_k) = (0.0f64, 0.0f64);
        for _ in 0..100 {
            let cam = random_camera(&mut rng, model);
            for i in 0..20 {
                let mut p = random_point_in_domain(&mut rng, &cam, 0.9);
                if i == 0 {
                    p = Vec3::new(0.0, 0.0, p.norm()); // on the optical axis
                }
                let (px, jp, jk) = cam.project_with_jacobians(&p).expect("in domain");
                assert_eq!(Some(px), cam.project(&p), "project and project_with_jacobians differ");
                let hp = Vec3::repeat(1e-6 * p.norm());
                let num_p = numeric_jacobian(|q| cam.project(q).unwrap(), &p, &hp);
                worst_p = worst_p.max(scaled_err(&jp, &num_p));

                let k0 = SMatrix::<f64, MAX_INTRINSICS, 1>::from_row_slice(&cam.params());
                // The pixel is linear in every intrinsic, so a large step only removes rounding noise.
                let hk = k0.map(|v| 1e-4 * v.abs().max(1.0));
                let num_k = numeric_jacobian(
                    |k| {
                        let mut c = cam;
                        c.set_params(k.as_slice());
                        c.project(&p).unwrap()
                    },
                    &k0,
                    &hk,
                );
                worst_k = worst_k.max(scaled_err(&jk, &num_k));
                for c in cam.num_params()..MAX_INTRINSICS {
                    assert_eq!(jk.column(c).norm(), 0.0, "unused intrinsics column {c} not zero");
                }
            }
        }
        println!("{model:?}: worst Jacobian error point {worst_p:.2e}, intrinsics {worst_k:.2e}");
        assert!(worst_p < 1e-6 && worst_k < 1e-6, "{model:?}: {worst_p:e} {worst_k:e}");
    }
}

#[test]
fn fisheye_jacobians_hold_behind_the_image_plane() {
    let cam = fisheye(1920, 1920, 200.0, [0.02, -0.01, 0.002, -0.0005]);
    let mut rng = Rng(7);
    let mut worst = 0.0f64;
    for _ in 0..2000 {
        let theta = rng.uniform(1.4, 0.99 * cam.max_valid_radius());
        let phi = rng.uniform(0.0, 2.0 * PI);
        let p = Vec3::new(theta.sin() * phi.cos(), theta.sin() * phi.sin(), theta.cos()) * 2.0;
        let (_, jp, _) = cam.project_with_jacobians(&p).expect("inside 110°");
        let num = numeric_jacobian(|q| cam.project(q).unwrap(), &p, &Vec3::repeat(1e-6));
        worst = worst.max(scaled_err(&jp, &num));
        let back = cam.unproject(&cam.project(&p).unwrap()).expect("invertible");
        assert!((back - p.normalize()).norm() < 1e-10);
    }
    println!("fisheye point Jacobian beyond 80°: worst error {worst:.2e}");
    assert!(worst < 1e-6);
}

#[test]
fn distort_jacobian_matches_central_differences() {
    let mut rng = Rng(8);
    let mut worst = 0.0f64;
    for model in [CameraModel::PinholeRadtan, CameraModel::Fisheye] {
        for _ in 0..200 {
            let cam = random_camera(&mut rng, model);
            let p = random_point_in_domain(&mut rng, &cam, 0.9);
            if p.z <= 0.05 {
                continue;
            }
            let xy = Vec2::new(p.x / p.z, p.y / p.z);
            let (d, j) = cam.distort_with_jacobian(&xy);
            assert!((d - cam.distort(&xy)).norm() < 1e-15);
            let num = numeric_jacobian(|v| cam.distort(v), &xy, &Vec2::repeat(1e-7));
            worst = worst.max(scaled_err(&j, &num));
            let back =
                cam.undistort(&d).unwrap_or_else(|| panic!("undistort {d:?} {xy:?} {cam:?}"));
            assert!((back - xy).norm() < 1e-9 * (1.0 + xy.norm()));
        }
    }
    println!("distort Jacobian worst error {worst:.2e}");
    assert!(worst < 1e-6);
}

/// Dense grid over the whole image, border to border (pixel edges), corners included.
fn image_grid(cam: &Camera, nx: usize, ny: usize) -> impl Iterator<Item = Vec2> + '_ {
    let (w, h) = (f64::from(cam.width), f64::from(cam.height));
    (0..=ny).flat_map(move |j| {
        (0..=nx).map(move |i| {
            Vec2::new(-0.5 + w * i as f64 / nx as f64, -0.5 + h * j as f64 / ny as f64)
        })
    })
}

/// Worst |project(unproject(px)) − px| over the grid; panics if any pixel does not invert.
fn round_trip_whole_image(name: &str, cam: &Camera) -> f64 {
    let mut worst = 0.0f64;
    for px in image_grid(cam, 192, 120) {
        let ray = cam.unproject(&px).unwrap_or_else(|| panic!("{name}: no ray for {px:?}"));
        assert!((ray.norm() - 1.0).abs() < 1e-14, "{name}: ray not unit");
        let back =
            cam.project(&ray).unwrap_or_else(|| panic!("{name}: ray of {px:?} out of domain"));
        worst = worst.max((back - px).norm());
    }
    println!("{name}: whole-image round trip worst {worst:.2e} px");
    assert!(worst < 1e-8, "{name}: round trip error {worst:e} px");
    worst
}

#[test]
fn radtan_round_trips_over_whole_image() {
    let cases = [
        ("radtan k1=-0.4 k2=0.15", radtan(1920, 1200, 100.0, [-0.4, 0.15, 0.0, 0.0, 0.0])),
        (
            "radtan k1=-0.4 k2=0.15 k3=-0.02 p",
            radtan(1920, 1200, 100.0, [-0.4, 0.15, 1e-3, -8e-4, -0.02]),
        ),
        ("radtan k1=+0.4 k2=0.1", radtan(1920, 1200, 90.0, [0.4, 0.1, 5e-4, 5e-4, 0.0])),
        ("radtan k1=+0.4 k2=-0.1 k3=0.05", radtan(1280, 800, 70.0, [0.4, -0.1, 0.0, 0.0, 0.05])),
        ("radtan typical", radtan(1920, 1200, 75.0, [-0.28, 0.079, 1.2e-4, -2.1e-4, -0.012])),
        ("radtan mild", radtan(640, 480, 60.0, [0.05, -0.12, 0.0, 0.0, 0.08])),
    ];
    for (name, cam) in cases.iter() {
        round_trip_whole_image(name, cam);
    }
}

#[test]
fn fisheye_round_trips_over_whole_image() {
    let cases = [
        ("fisheye 120° typical", fisheye(1920, 1200, 120.0, [0.05, -0.02, 0.005, -0.001])),
        ("fisheye 120° negative", fisheye(1920, 1200, 120.0, [-0.013, -0.006, 0.0015, -3e-4])),
        ("fisheye 120° equidistant", fisheye(1280, 960, 120.0, [0.0; 4])),
        (
            "fisheye 170° (corners past 90°)",
            fisheye(1920, 1080, 170.0, [0.02, -0.01, 0.002, -5e-4]),
        ),
    ];
    for (name, cam) in cases.iter() {
        round_trip_whole_image(name, cam);
    }
}

#[test]
fn fisheye_sees_past_ninety_degrees_inside_its_image_circle() {
    // 200° across the width: corners lie outside the image circle (rays past 110°).
    let cam = fisheye(1600, 1600, 200.0, [0.02, -0.01, 0.002, -5e-4]);
    let edge = cam.fisheye_theta_d(cam.max_valid_radius());
    let (mut inverted, mut beyond_90, mut refused) = (0, 0, 0);
    for px in image_grid(&cam, 100, 100) {
        let d = cam.to_normalized(&px).unwrap();
        match cam.unproject(&px) {
            Some(ray) => {
                inverted += 1;
                beyond_90 += usize::from(ray.z < 0.0);
                assert!((cam.project(&ray).unwrap() - px).norm() < 1e-8);
            }
            None => {
                refused += 1;
                assert!(d.norm() > edge * (1.0 - 1e-12), "refused a pixel inside the image circle");
            }
        }
    }
    println!("fisheye 200°: {inverted} pixels inverted ({beyond_90} past 90°), {refused} outside");
    assert!(beyond_90 > 100 && refused > 100);
    assert!(cam.project(&Vec3::new(1.0, 0.0, -1.0)).is_none(), "135° is past 110°");
}

#[test]
fn unproject_converges_over_the_whole_monotonic_domain() {
    // For random cameras, every ray up to 99.5 % of the fold radius (capped at r = 3 for
    // radtan) projects and inverts back; the pixel need not be on the image.
    let mut rng = Rng(9);
    for model in [CameraModel::PinholeRadtan, CameraModel::Fisheye] {
        let (mut worst, mut n, mut refused) = (0.0f64, 0, 0);
        for _ in 0..300 {
            let cam = random_camera(&mut rng, model);
            for _ in 0..50 {
                let p = random_point_in_domain(&mut rng, &cam, 0.995);
                // Tangential terms may fold the map a little before the radial fold.
                let Some(px) = cam.project(&p) else {
                    assert!(model == CameraModel::PinholeRadtan, "fisheye refused {p:?}");
                    refused += 1;
                    continue;
                };
                let ray =
                    cam.unproject(&px).unwrap_or_else(|| panic!("no ray {p:?} {px:?} {cam:?}"));
                worst = worst.max((ray - p.normalize()).norm());
                n += 1;
            }
        }
        println!("{model:?}: {n} random rays inverted, worst ray error {worst:.2e}; {refused} refused by project near the fold");
        assert!(worst < 1e-9 && refused * 100 < n);
    }
}

#[test]
fn barrel_fold_is_refused_both_ways() {
    // k1 = −0.4 alone folds at r = 1/√1.2: beyond it projection and inversion refuse.
    let cam = radtan(1920, 1200, 80.0, [-0.4, 0.0, 0.0, 0.0, 0.0]);
    let r_fold = cam.max_valid_radius();
    assert!((r_fold - (1.0f64 / 1.2).sqrt()).abs() < 1e-12, "fold radius {r_fold}");
    assert!(cam.project(&Vec3::new(r_fold * 1.001, 0.0, 1.0)).is_none());
    assert!(cam.project(&Vec3::new(r_fold * 0.999, 0.0, 1.0)).is_some());
    assert!(cam.project(&Vec3::new(0.0, 0.0, -1.0)).is_none(), "behind the camera");
    // The distorted image of the fold radius is the largest invertible one.
    let rd_fold = r_fold * (1.0 - 0.4 * r_fold * r_fold);
    let inside = cam.to_pixel(&Vec2::new(rd_fold * 0.999, 0.0));
    let outside = cam.to_pixel(&Vec2::new(rd_fold * 1.001, 0.0));
    let ray = cam.unproject(&inside).expect("inside the fold");
    assert!(ray.x / ray.z < r_fold);
    assert!(cam.unproject(&outside).is_none(), "past the fold must be refused");
    // Without the fold (k2 = 0.15) the model is monotonic everywhere.
    assert_eq!(
        radtan(640, 480, 60.0, [-0.4, 0.15, 0.0, 0.0, 0.0]).max_valid_radius(),
        f64::INFINITY
    );
}

#[test]
fn from_fov_puts_the_half_fov_ray_on_the_border() {
    for (model, hfov, d) in [
        (CameraModel::PinholeRadtan, 90.0, [0.0; 5]),
        (CameraModel::PinholeRadtan, 100.0, [-0.3, 0.1, 0.0, 0.0, 0.0]),
        (CameraModel::Fisheye, 120.0, [0.0; 5]),
        (CameraModel::Fisheye, 190.0, [0.03, -0.01, 0.001, 0.0, 0.0]),
    ] {
        let cam = Camera::try_from_fov(model, 1920, 1080, hfov, d).unwrap();
        assert_eq!((cam.cx, cam.cy, cam.fx), (959.5, 539.5, cam.fy));
        let ray = cam.unproject(&Vec2::new(-0.5, cam.cy)).unwrap();
        let angle = ray.z.acos().to_degrees();
        assert!((angle - hfov / 2.0).abs() < 1e-9, "{model:?} {hfov}: border at {angle}°");
    }
    let plain = Camera::try_from_fov(CameraModel::Fisheye, 1000, 1000, 120.0, [0.0; 5]).unwrap();
    assert!((plain.fx - 500.0 / (PI / 3.0)).abs() < 1e-9, "equidistant f");
    assert!(Camera::try_from_fov(CameraModel::PinholeRadtan, 640, 480, 180.0, [0.0; 5]).is_none());
    assert!(Camera::try_from_fov(
        CameraModel::Fisheye,
        640,
        480,
        2.0 * FISHEYE_MAX_THETA.to_degrees() + 1.0,
        [0.0; 5]
    )
    .is_none());
    assert!(Camera::try_from_fov(CameraModel::Fisheye, 0, 480, 90.0, [0.0; 5]).is_none());
    assert!(
        Camera::try_from_fov(
            CameraModel::PinholeRadtan,
            640,
            480,
            150.0,
            [-0.4, 0.0, 0.0, 0.0, 0.0]
        )
        .is_none(),
        "past the fold"
    );
    // The infallible form agrees where the fallible one succeeds, and otherwise still
    // gives a usable camera.
    let d = [-0.2, 0.05, 0.0, 0.0, 0.0];
    assert_eq!(
        Some(Camera::from_fov(CameraModel::PinholeRadtan, 640, 480, 90.0, d)),
        Camera::try_from_fov(CameraModel::PinholeRadtan, 640, 480, 90.0, d)
    );
    for (model, hfov) in [
        (CameraModel::PinholeRadtan, 200.0),
        (CameraModel::Fisheye, 400.0),
        (CameraModel::PinholeRadtan, f64::NAN),
        (CameraModel::Fisheye, -5.0),
    ] {
        let cam = Camera::from_fov(model, 640, 480, hfov, [0.0; 5]);
        assert!(cam.fx.is_finite() && cam.fx > 0.0, "{model:?} {hfov}: fx {}", cam.fx);
        let centre = cam.project(&Vec3::new(0.0, 0.0, 1.0)).unwrap();
        assert_eq!(centre, Vec2::new(319.5, 239.5));
    }
}

#[test]
fn params_round_trip_and_order() {
    let mut cam = radtan(640, 480, 60.0, [0.1, 0.2, 0.3, 0.4, 0.5]);
    assert_eq!(cam.num_params(), 9);
    let p = cam.params();
    assert_eq!(p, [cam.fx, cam.fy, cam.cx, cam.cy, 0.1, 0.2, 0.3, 0.4, 0.5]);
    cam.set_params(&[1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0, 10.0]);
    assert_eq!(
        (cam.fx, cam.fy, cam.cx, cam.cy, cam.distortion),
        (1.0, 2.0, 3.0, 4.0, [5.0, 6.0, 7.0, 8.0, 9.0])
    );
    cam.set_params(&[11.0]);
    assert_eq!((cam.fx, cam.fy), (11.0, 2.0), "a short slice sets only its values");
    let mut fe = fisheye(640, 480, 120.0, [0.1, 0.2, 0.3, 0.4]);
    assert_eq!(fe.num_params(), 8);
    assert_eq!(fe.params()[4..], [0.1, 0.2, 0.3, 0.4, 0.0]);
    fe.set_params(&[1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0]);
    assert_eq!(fe.distortion, [5.0, 6.0, 7.0, 8.0, 0.0], "fisheye ignores a ninth value");
}

#[test]
fn malformed_inputs_give_none_not_panics() {
    let cam = radtan(640, 480, 60.0, [-0.2, 0.05, 0.0, 0.0, 0.0]);
    let fe = fisheye(640, 480, 120.0, [0.0; 4]);
    for c in [cam, fe] {
        assert!(c.project(&Vec3::new(f64::NAN, 0.0, 1.0)).is_none());
        assert!(c.project(&Vec3::zeros()).is_none());
        assert!(c.unproject(&Vec2::new(f64::NAN, 1.0)).is_none());
        assert!(c.unproject(&Vec2::new(1e300, 1e300)).is_none());
        let mut zero_f = c;
        zero_f.fx = 0.0;
        assert!(zero_f.unproject(&Vec2::new(1.0, 1.0)).is_none());
    }
    assert!(fe.project(&Vec3::new(0.0, 0.0, -1.0)).is_none(), "θ = 180° is outside 110°");
}

// ---------------------------------------------------------------- OpenCV agreement

#[cfg(feature = "std")]
#[test]
fn agrees_with_opencv_projectpoints() {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/opencv_projections.json");
    let text = std::fs::read_to_string(path).expect("tests/data/opencv_projections.json");
    let doc: serde_json::Value = serde_json::from_str(&text).expect("valid JSON");
    let f = |v: &serde_json::Value| v.as_f64().expect("number");
    let v3 = |v: &serde_json::Value| Vec3::new(f(&v[0]), f(&v[1]), f(&v[2]));
    let mut worst = [0.0f64; 2];
    let mut n = 0;
    for case in doc["cases"].as_array().expect("cases") {
        let model: CameraModel = serde_json::from_value(case["model"].clone()).expect("model");
        let mut distortion = [0.0; 5];
        for (d, v) in distortion.iter_mut().zip(case["distortion"].as_array().unwrap()) {
            *d = f(v);
        }
        let cam = Camera {
            model,
            width: case["width"].as_u64().unwrap() as u32,
            height: case["height"].as_u64().unwrap() as u32,
            fx: f(&case["fx"]),
            fy: f(&case["fy"]),
            cx: f(&case["cx"]),
            cy: f(&case["cy"]),
            distortion,
        };
        let pose = Se3::from_rvec_t(&v3(&case["rvec"]), &v3(&case["tvec"]));
        let pixels = case["pixels"].as_array().unwrap();
        for (p, q) in case["points"].as_array().unwrap().iter().zip(pixels) {
            let expected = Vec2::new(f(&q[0]), f(&q[1]));
            let got = cam.project(&pose.act(&v3(p))).expect("OpenCV point inside our domain");
            let rel = (got - expected).norm() / expected.norm();
            let slot = usize::from(model == CameraModel::Fisheye);
            worst[slot] = worst[slot].max(rel);
            n += 1;
        }
    }
    println!(
        "OpenCV agreement over {n} points: worst relative error radtan {:.2e}, fisheye {:.2e}",
        worst[0], worst[1]
    );
    assert!(n >= 300);
    assert!(worst[0] < 1e-9 && worst[1] < 1e-9);
}
