//! The six-bar's own effects as a few basis functions over the measured poses: the
//! linearised loop closure's responses ([`crate::loop_closure`]) reduced by SVD to what the
//! five-bar's constant parameters cannot do.
//!
//! * **`parallelogram_mismatch`**: the tool displacement the loops cause per µm of each raw
//!   error (bar lengths, pin positions, bearings: 24 of them), *minus* the distal bars' elastic
//!   stretch (that is `link_stretch`), with the span of the five-bar's constant parameters
//!   (link lengths, encoder offsets, base offset, instrument frame and scale) projected out over
//!   the data: the SVD of that 2n × 24 matrix gives the directions of raw-error space that move
//!   the tool most in ways no five-bar can; the first [`N_MISMATCH`] are the modes. Each mode's
//!   parameter is its RMS tool displacement over the data (µm).
//! * **`link_stretch`**: the elastic elongation of the distal bars, ε_Q1, ε_Q2 (θ1, θ2), per raw
//!   error: a multiple of the loop's one self-stress state (so both bars stretch together, in the
//!   design's ratio, and as functions of the absolute link angles, not of the five-bar's shape
//!   alone). The SVD of their tool displacement `∂C/∂b·ε_Q1 + ∂C/∂c·ε_Q2` (2n × 24) has rank 5
//!   on the paper machine (singular values 1, 0.15, 0.11, 0.02, 0.01): the [`N_STRETCH`] modes
//!   are all of it. Not projected: a constant stretch is physically part of a stretch, so
//!   "stretch alone" is explained by `link_stretch` alone; its overlap with `link_lengths` is
//!   reported by the confounding analysis. Each parameter is the RMS length change over the data
//!   and both bars (µm).
//!
//! Why these counts: over the paper machine's workspace the mismatch's singular values fall
//! 1, 0.87, 0.34, 0.23, 0.14, ...; with four mismatch modes and the stretch's five the six-bar
//! error of the `paper` plant and of random σ = 50 µm plants (1.5–2.8 µm RMS beyond the
//! five-bar) is represented to ≤ 0.2 µm RMS (docs/design/diagnosis.md), below a 1 µm instrument.
//!
//! For "add it to the model" each mode is also kept as the raw-error combination it stands for
//! (and, for the mismatch, the five-bar parameter change its projection subtracted), so a fitted
//! amplitude becomes effective six-bar errors that [`crate::loop_closure::response`] evaluates
//! at any configuration.
//!
//! Cost: one loop-closure response per point (a few µs) and three thin SVDs of 2n × 24.

use crate::loop_closure::{response, Response, SixBarDesign, N_RAW};
use crate::numeric::subspace::orthonormal_basis;
use kinematics_core::FiveBar;
use nalgebra::DMatrix;

/// Mismatch modes kept.
pub const N_MISMATCH: usize = 4;
/// Stretch modes kept per distal bar.
pub const N_STRETCH: usize = 5;
/// Fewest points on which the modes are computed (fewer: the effects are not offered).
pub const MIN_POINTS: usize = 30;

/// The modes over one data set.
#[derive(Clone, Debug)]
pub struct SixBarModes {
    /// Per point: tool displacement (µm, x and y) of each mismatch mode at unit amplitude.
    pub mismatch_um: Vec<[[f64; 2]; N_MISMATCH]>,
    /// Per point: length change (µm) of distal bar b (arm 0) and c (arm 1) per unit amplitude of
    /// each stretch mode.
    pub stretch: Vec<[[f64; N_STRETCH]; 2]>,
    /// Raw errors (µm) one unit of each mismatch mode stands for.
    pub mismatch_raw: [[f64; N_RAW]; N_MISMATCH],
    /// The five-bar parameter change (in the problem's units, by parameter index) one unit of
    /// each mismatch mode includes with the opposite sign (its projection).
    pub mismatch_five_bar: [Vec<(usize, f64)>; N_MISMATCH],
    /// Raw errors (µm) one unit of each stretch mode stands for (both distal bars' elongation
    /// under the same self-stress).
    pub stretch_raw: [[f64; N_RAW]; N_STRETCH],
}

/// Per-point loop responses, or why a point has none.
pub fn responses(
    model: &FiveBar<f64>,
    design: &SixBarDesign,
    thetas: &[[f64; 2]],
) -> Vec<Option<Response>> {
    thetas
        .iter()
        .map(|&th| response(model, design, th).ok())
        .collect()
}

/// Computes the modes. `five_bar` is the 2n × k matrix of the tool displacement per unit of
/// each five-bar parameter listed in `five_bar_params` (x, y interleaved per point); responses
/// must all be present. `Err` says why the modes do not exist on these poses.
pub fn modes(
    responses: &[Response],
    five_bar: &DMatrix<f64>,
    five_bar_params: &[usize],
) -> Result<SixBarModes, String> {
    let n = responses.len();
    if n < MIN_POINTS {
        return Err(format!("{n} points: too few to tell the six-bar's own effects from the five-bar's (need {MIN_POINTS})"));
    }
    let sqrt_n = (n as f64).sqrt();
    // Stretch part of each raw response: ∂C/∂b·ε_Q1 + ∂C/∂c·ε_Q2.
    let stretch_tool = |r: &Response, raw: usize, arm: usize| -> [f64; 2] {
        let e = r.distal_elongation[arm][raw];
        [r.dc_db[arm][0] * e, r.dc_db[arm][1] * e]
    };
    let mut mism = DMatrix::<f64>::zeros(2 * n, N_RAW);
    for (i, r) in responses.iter().enumerate() {
        for raw in 0..N_RAW {
            let (s0, s1) = (stretch_tool(r, raw, 0), stretch_tool(r, raw, 1));
            mism[(2 * i, raw)] = r.tool[raw][0] - s0[0] - s1[0];
            mism[(2 * i + 1, raw)] = r.tool[raw][1] - s0[1] - s1[1];
        }
    }
    let q = orthonormal_basis(five_bar);
    let projected = &mism - &q * (q.transpose() * &mism);
    let svd = projected.clone().svd(true, true);
    let (u, vt) = (svd.u.expect("u requested"), svd.v_t.expect("v requested"));
    let order = descending(svd.singular_values.as_slice());
    let s_max = svd.singular_values[order[0]];
    if !(s_max > 1e-9) {
        return Err("the loops' responses are all five-bar-like on these poses".into());
    }
    let pinv = pseudo_inverse(five_bar);
    let mut out = SixBarModes {
        mismatch_um: vec![[[0.0; 2]; N_MISMATCH]; n],
        stretch: vec![[[0.0; N_STRETCH]; 2]; n],
        mismatch_raw: [[0.0; N_RAW]; N_MISMATCH],
        mismatch_five_bar: std::array::from_fn(|_| Vec::new()),
        stretch_raw: [[0.0; N_RAW]; N_STRETCH],
    };
    for (m, &k) in order.iter().take(N_MISMATCH).enumerate() {
        let s = svd.singular_values[k];
        if s < 1e-6 * s_max {
            continue; // Not in the data: the mode stays zero (its parameter is not identifiable).
        }
        for (i, point) in out.mismatch_um.iter_mut().enumerate() {
            point[m] = [u[(2 * i, k)] * sqrt_n, u[(2 * i + 1, k)] * sqrt_n];
        }
        let scale = sqrt_n / s;
        let v = vt.row(k).transpose();
        for raw in 0..N_RAW {
            out.mismatch_raw[m][raw] = v[raw] * scale;
        }
        // The five-bar part the projection removed: c = F⁺·(M·v).
        let c = &pinv * (&mism * &v);
        out.mismatch_five_bar[m] = five_bar_params
            .iter()
            .zip(c.iter())
            .map(|(&p, &c)| (p, c * scale))
            .collect();
    }
    // Stretch: both distal bars' elongation under the one self-stress, as it moves the tool.
    let mut tool = DMatrix::<f64>::zeros(2 * n, N_RAW);
    for (i, r) in responses.iter().enumerate() {
        for raw in 0..N_RAW {
            let (t0, t1) = (stretch_tool(r, raw, 0), stretch_tool(r, raw, 1));
            tool[(2 * i, raw)] = t0[0] + t1[0];
            tool[(2 * i + 1, raw)] = t0[1] + t1[1];
        }
    }
    let svd = tool.svd(false, true);
    let vt = svd.v_t.expect("v requested");
    let order = descending(svd.singular_values.as_slice());
    let s_max = svd.singular_values[order[0]];
    if !(s_max > 1e-12) {
        return Err("the distal bars carry no self-stress on these poses".into());
    }
    for (m, &k) in order.iter().take(N_STRETCH).enumerate() {
        if svd.singular_values[k] < 1e-6 * s_max {
            continue;
        }
        let v = vt.row(k).transpose();
        let f: Vec<[f64; 2]> = responses
            .iter()
            .map(|r| {
                [0, 1].map(|arm| {
                    (0..N_RAW)
                        .map(|raw| r.distal_elongation[arm][raw] * v[raw])
                        .sum()
                })
            })
            .collect();
        // Unit RMS over the data and both bars.
        let rms =
            (f.iter().map(|x| x[0] * x[0] + x[1] * x[1]).sum::<f64>() / (2 * n) as f64).sqrt();
        if !(rms > 0.0) {
            continue;
        }
        for (point, fi) in out.stretch.iter_mut().zip(&f) {
            point[0][m] = fi[0] / rms;
            point[1][m] = fi[1] / rms;
        }
        for raw in 0..N_RAW {
            out.stretch_raw[m][raw] = v[raw] / rms;
        }
    }
    Ok(out)
}

/// Indices of `s` sorted by decreasing value (nalgebra's SVD does not promise an order).
fn descending(s: &[f64]) -> Vec<usize> {
    let mut idx: Vec<usize> = (0..s.len()).collect();
    idx.sort_by(|&a, &b| s[b].total_cmp(&s[a]));
    idx
}

/// Moore–Penrose pseudo-inverse (relative tolerance 1e-9).
fn pseudo_inverse(a: &DMatrix<f64>) -> DMatrix<f64> {
    if a.ncols() == 0 {
        return DMatrix::zeros(0, a.nrows());
    }
    let svd = a.clone().svd(true, true);
    let smax = svd.singular_values.max();
    svd.pseudo_inverse(1e-9 * smax)
        .unwrap_or_else(|_| DMatrix::zeros(a.ncols(), a.nrows()))
}
