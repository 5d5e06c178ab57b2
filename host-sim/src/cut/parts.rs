//! Part programs a laser-cutting shop cuts, written as its CAM writes them (pierce with a
//! dwell, a lead-in, the contour, beam off, rapid to the next): the examples shipped in
//! `host-sim/parts/` (a test checks the files are these), the nest of 1000 contours the
//! planner's time is measured on, and random programs for the property tests.
//!
//! Sheet: 1 mm mild steel on a fibre laser: contours at 12 m/min, small holes at 6 m/min (CAM
//! slows small holes down), a 50 ms pierce.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::f64::consts::{PI, TAU};
use std::fmt::Write as _;

/// The pierce dwell (s).
pub const PIERCE_S: f64 = 0.05;
/// Contour feed (mm/min).
pub const FEED: f64 = 12_000.0;
/// Feed of holes below 20 mm (mm/min).
pub const HOLE_FEED: f64 = 6_000.0;

/// A program being written.
pub struct Writer {
    text: String,
}

fn n(v: f64) -> String {
    let s = format!("{v:.4}");
    let s = s.trim_end_matches('0').trim_end_matches('.');
    if s == "-0" {
        "0".into()
    } else {
        s.to_string()
    }
}

impl Writer {
    /// A program with its header comment.
    pub fn new(title: &str) -> Writer {
        let mut text = String::new();
        let _ = writeln!(text, "%\n({title})\nG21 G90 G17 G40 G94");
        Writer { text }
    }

    fn line(&mut self, s: &str) {
        self.text.push_str(s);
        self.text.push('\n');
    }

    /// Rapid to `p`, beam on, pierce.
    pub fn pierce(&mut self, p: [f64; 2]) {
        self.line(&format!("G0 X{} Y{}", n(p[0]), n(p[1])));
        self.line("M3 S1000");
        self.line(&format!("G4 P{}", n(PIERCE_S)));
    }

    /// Beam off.
    pub fn off(&mut self) {
        self.line("M5");
    }

    /// A closed polygon from its first vertex, at `feed`, with a lead-in from `inside`.
    pub fn polygon(&mut self, inside: [f64; 2], v: &[[f64; 2]], feed: f64) {
        self.pierce(inside);
        self.line(&format!("G1 X{} Y{} F{}", n(v[0][0]), n(v[0][1]), n(feed)));
        for p in v.iter().skip(1).chain(std::iter::once(&v[0])) {
            self.line(&format!("X{} Y{}", n(p[0]), n(p[1])));
        }
        self.off();
    }

    /// A hole of radius `r` about `c`: pierce at the centre, a straight lead-in, the circle.
    pub fn hole(&mut self, c: [f64; 2], r: f64, feed: f64) {
        self.pierce(c);
        self.line(&format!("G1 X{} F{}", n(c[0] + r), n(feed)));
        self.line(&format!("G3 I{} J0", n(-r)));
        self.off();
    }

    /// A rectangle with rounded corners (radius `r`), lead-in from its inside.
    pub fn rounded_rect(&mut self, lo: [f64; 2], hi: [f64; 2], r: f64, feed: f64) {
        let inside = [lo[0] + r + 2.0, (lo[1] + hi[1]) / 2.0];
        self.pierce(inside);
        let y0 = (lo[1] + hi[1]) / 2.0;
        self.line(&format!("G1 X{} Y{} F{}", n(lo[0]), n(y0), n(feed)));
        self.line(&format!("Y{}", n(lo[1] + r)));
        self.line(&format!("G3 X{} Y{} I{} J0", n(lo[0] + r), n(lo[1]), n(r)));
        self.line(&format!("G1 X{}", n(hi[0] - r)));
        self.line(&format!("G3 X{} Y{} I0 J{}", n(hi[0]), n(lo[1] + r), n(r)));
        self.line(&format!("G1 Y{}", n(hi[1] - r)));
        self.line(&format!("G3 X{} Y{} I{} J0", n(hi[0] - r), n(hi[1]), n(-r)));
        self.line(&format!("G1 X{}", n(lo[0] + r)));
        self.line(&format!("G3 X{} Y{} I0 J{}", n(lo[0]), n(hi[1] - r), n(-r)));
        self.line(&format!("G1 Y{}", n(y0)));
        self.off();
    }

    /// The program's text, ended.
    pub fn finish(mut self) -> String {
        self.line("M30\n%");
        self.text
    }
}

/// A star's vertices: `points` tips at `r_out`, valleys at `r_in`, about `c`.
fn star(c: [f64; 2], points: usize, r_out: f64, r_in: f64, turn: f64) -> Vec<[f64; 2]> {
    (0..2 * points)
        .map(|k| {
            let a = turn + PI * k as f64 / points as f64;
            let r = if k % 2 == 0 { r_out } else { r_in };
            [c[0] + r * a.cos(), c[1] + r * a.sin()]
        })
        .collect()
}

/// A plate of small holes: 8 × 6 holes of 6 mm on a 16 mm pitch, and the plate.
pub fn holes() -> String {
    let mut w = Writer::new("plate of small holes: 48 x D6 on 16 mm, plate 150 x 118, 1 mm steel");
    let o = [200.0, 300.0];
    for j in 0..6 {
        for i in 0..8 {
            // Serpentine order, as a CAM's nearest-neighbour ordering gives.
            let i = if j % 2 == 0 { i } else { 7 - i };
            w.hole(
                [o[0] + 19.0 + 16.0 * i as f64, o[1] + 19.0 + 16.0 * j as f64],
                3.0,
                HOLE_FEED,
            );
        }
    }
    w.rounded_rect(o, [o[0] + 150.0, o[1] + 118.0], 5.0, FEED);
    w.finish()
}

/// Stars of sharp corners: 3 × 3 twelve-point stars (40 mm across), each a contour of 24
/// corners.
pub fn stars() -> String {
    let mut w = Writer::new("star plate: 9 twelve-point stars, 24 sharp corners each, 1 mm steel");
    for j in 0..3 {
        for i in 0..3 {
            let c = [500.0 + 50.0 * i as f64, 500.0 + 50.0 * j as f64];
            w.polygon(c, &star(c, 12, 20.0, 11.0, 0.1 * (i + 3 * j) as f64), FEED);
        }
    }
    w.finish()
}

/// A test piece in the spirit of ISO 10791-7 / NAS 979: a square, a diamond inside it, a
/// circle inside that, a face at 3° to the x axis, four small holes, cut at one feed.
pub fn test_piece() -> String {
    let mut w = Writer::new(
        "contouring test piece in the spirit of ISO 10791-7 and NAS 979: square, diamond, circle, 3 deg face, holes",
    );
    let c = [800.0, 800.0];
    for (dx, dy) in [(-65.0, -65.0), (65.0, -65.0), (65.0, 65.0), (-65.0, 65.0)] {
        w.hole([c[0] + dx, c[1] + dy], 4.0, HOLE_FEED);
    }
    // The circle (R 40), lead-in from its centre.
    w.pierce(c);
    w.line_feed([c[0] + 40.0, c[1]], FEED);
    w.raw("G3 I-40 J0");
    w.off();
    // The diamond (the square turned 45°, 110 mm across its corners).
    let d: Vec<[f64; 2]> = (0..4)
        .map(|k| {
            let a = PI / 2.0 * k as f64;
            [c[0] + 55.0 * a.cos(), c[1] + 55.0 * a.sin()]
        })
        .collect();
    w.polygon([c[0] + 45.0, c[1]], &d, FEED);
    // The square with one face at 3°.
    let s = 80.0;
    let slope = (3.0f64).to_radians().tan() * 2.0 * s;
    let sq = [
        [c[0] - s, c[1] - s],
        [c[0] + s, c[1] - s + slope],
        [c[0] + s, c[1] + s],
        [c[0] - s, c[1] + s],
    ];
    w.polygon([c[0] - s + 5.0, c[1]], &sq, FEED);
    w.finish()
}

/// A nest of small parts spread over the sheet: `nx × ny` parts on a `pitch` lattice from
/// `origin`, alternating a washer (two circles) and a bracket (rounded rectangle, two holes).
pub fn nest_of(nx: usize, ny: usize, origin: [f64; 2], pitch: [f64; 2]) -> String {
    let mut w = Writer::new(&format!(
        "nest: {} small parts, washers and brackets, spread over the sheet",
        nx * ny
    ));
    for j in 0..ny {
        for i in 0..nx {
            let i = if j % 2 == 0 { i } else { nx - 1 - i };
            let c = [
                origin[0] + pitch[0] * i as f64,
                origin[1] + pitch[1] * j as f64,
            ];
            if (i + j) % 2 == 0 {
                w.hole(c, 6.0, HOLE_FEED);
                w.pierce([c[0] + 9.0, c[1]]);
                w.line_feed([c[0] + 15.0, c[1]], FEED);
                w.raw("G3 I-15 J0");
                w.off();
            } else {
                w.hole([c[0] - 12.0, c[1]], 2.5, HOLE_FEED);
                w.hole([c[0] + 12.0, c[1]], 2.5, HOLE_FEED);
                w.rounded_rect(
                    [c[0] - 20.0, c[1] - 10.0],
                    [c[0] + 20.0, c[1] + 10.0],
                    4.0,
                    FEED,
                );
            }
        }
    }
    w.finish()
}

/// The example nest: 5 × 8 parts, 250 mm apart over the sheet.
pub fn nest() -> String {
    nest_of(5, 8, [150.0, 200.0], [250.0, 350.0])
}

/// The nest of 1000 contours the planner's time is measured on (400 parts: 200 washers of
/// 2 contours, 200 brackets of 3).
pub fn nest_1000() -> String {
    nest_of(20, 20, [60.0, 60.0], [70.0, 145.0])
}

/// A long frame: a 1300 × 2800 mm rectangle and a 1200 × 2700 mm opening, slow (a thick
/// sheet's 3 m/min).
pub fn frame() -> String {
    let mut w = Writer::new("long frame: 1300 x 2800 outline, 1200 x 2700 opening, 3 m/min");
    let f = 3000.0;
    let inner = [
        [150.0, 150.0],
        [1350.0, 150.0],
        [1350.0, 2850.0],
        [150.0, 2850.0],
    ];
    // Lead-ins at the first corner: from inside the opening, from outside the outline.
    w.polygon([160.0, 160.0], &inner, f);
    let outer = [
        [100.0, 100.0],
        [100.0, 2900.0],
        [1400.0, 2900.0],
        [1400.0, 100.0],
    ];
    w.polygon([90.0, 90.0], &outer, f);
    w.finish()
}

impl Writer {
    fn line_feed(&mut self, p: [f64; 2], feed: f64) {
        self.line(&format!("G1 X{} Y{} F{}", n(p[0]), n(p[1]), n(feed)));
    }

    fn raw(&mut self, s: &str) {
        self.line(s);
    }
}

/// The shipped examples, by file name.
pub fn examples() -> Vec<(&'static str, String)> {
    vec![
        ("holes.nc", holes()),
        ("stars.nc", stars()),
        ("test-piece.nc", test_piece()),
        ("nest.nc", nest()),
        ("frame.nc", frame()),
    ]
}

/// A random program of `features` features somewhere on the sheet: holes (radius 1-20 mm),
/// polygons with sharp corners (3-12 vertices, 5-120 mm), rounded rectangles, arcs by `R`, an
/// incremental stretch, feeds 1-30 m/min, pierces with or without a dwell, rapids short and
/// long. Every point inside `[lo, hi]`.
pub fn random(seed: u64, features: usize, lo: [f64; 2], hi: [f64; 2]) -> String {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut w = Writer::new(&format!("random program {seed}"));
    // A cluster somewhere (most parts are local) or spread over the whole region.
    let spread = rng.random_bool(0.3);
    let centre = [
        rng.random_range(lo[0] + 150.0..hi[0] - 150.0),
        rng.random_range(lo[1] + 150.0..hi[1] - 150.0),
    ];
    let place = |rng: &mut ChaCha8Rng, r: f64| -> [f64; 2] {
        if spread {
            [
                rng.random_range(lo[0] + r..hi[0] - r),
                rng.random_range(lo[1] + r..hi[1] - r),
            ]
        } else {
            [
                (centre[0] + rng.random_range(-120.0..120.0)).clamp(lo[0] + r, hi[0] - r),
                (centre[1] + rng.random_range(-120.0..120.0)).clamp(lo[1] + r, hi[1] - r),
            ]
        }
    };
    for _ in 0..features {
        let feed = rng.random_range(1_000.0..30_000.0f64).round();
        match rng.random_range(0..5) {
            0 => {
                let r = rng.random_range(1.0..20.0f64);
                let c = place(&mut rng, r + 1.0);
                w.hole(c, (r * 100.0).round() / 100.0, feed);
            }
            1 => {
                let k = rng.random_range(3..13);
                let size = rng.random_range(5.0..120.0f64);
                let c = place(&mut rng, size + 1.0);
                let turn = rng.random_range(0.0..TAU);
                let v: Vec<[f64; 2]> = (0..k)
                    .map(|i| {
                        let a = turn + TAU * i as f64 / k as f64 + rng.random_range(-0.2..0.2);
                        let r = size * rng.random_range(0.5..1.0);
                        [c[0] + r * a.cos(), c[1] + r * a.sin()]
                    })
                    .collect();
                w.polygon(c, &v, feed);
            }
            2 => {
                let s = [
                    rng.random_range(10.0..150.0f64),
                    rng.random_range(10.0..150.0f64),
                ];
                let c = place(&mut rng, s[0].max(s[1]) / 2.0 + 1.0);
                let r = rng.random_range(0.5..(s[0].min(s[1]) / 2.0 - 0.1));
                w.rounded_rect(
                    [c[0] - s[0] / 2.0, c[1] - s[1] / 2.0],
                    [c[0] + s[0] / 2.0, c[1] + s[1] / 2.0],
                    (r * 100.0).round() / 100.0,
                    feed,
                );
            }
            3 => {
                // An S of two arcs by R, then straight back.
                let r = rng.random_range(3.0..40.0f64);
                let c = place(&mut rng, 2.0 * r + 2.0);
                w.pierce(c);
                w.line(&format!(
                    "G2 X{} Y{} R{} F{}",
                    n(c[0] + 2.0 * r),
                    n(c[1]),
                    n(r),
                    n(feed)
                ));
                w.line(&format!(
                    "G3 X{} Y{} R{}",
                    n(c[0] + 2.0 * r),
                    n(c[1] + 2.0 * r),
                    n(r)
                ));
                w.line(&format!("G1 X{} Y{}", n(c[0]), n(c[1])));
                w.off();
            }
            _ => {
                // An incremental zig-zag, beam on without a dwell (a flying pierce).
                let c = place(&mut rng, 40.0);
                w.line(&format!("G0 X{} Y{}", n(c[0]), n(c[1])));
                w.line("M3");
                w.line(&format!("G91 G1 X10 Y5 F{}", n(feed)));
                for k in 0..rng.random_range(2..8) {
                    let s = if k % 2 == 0 { -1.0 } else { 1.0 };
                    w.line(&format!(
                        "X{} Y{}",
                        n(rng.random_range(1.0..6.0)),
                        n(s * 5.0)
                    ));
                }
                w.line("G90");
                w.off();
            }
        }
    }
    w.finish()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cut::gcode::parse_program;
    use crate::gantry_spec::GantrySpec;

    #[test]
    fn the_shipped_parts_are_these_programs() {
        let dir = concat!(env!("CARGO_MANIFEST_DIR"), "/parts");
        for (name, text) in examples() {
            let shipped = std::fs::read_to_string(format!("{dir}/{name}"))
                .unwrap_or_else(|e| panic!("parts/{name}: {e}"));
            assert_eq!(shipped, text, "parts/{name} differs from parts::{name}");
            parse_program(&text, &GantrySpec::paper()).unwrap();
        }
    }

    #[test]
    fn random_programs_read() {
        for seed in 0..50 {
            let text = random(seed, 12, [20.0, 20.0], [1480.0, 2980.0]);
            parse_program(&text, &GantrySpec::paper())
                .unwrap_or_else(|e| panic!("{seed}: {e}\n{text}"));
        }
        let p = parse_program(&nest_1000(), &GantrySpec::paper()).unwrap();
        let contours = p
            .ops
            .iter()
            .filter(|o| matches!(o, crate::cut::gcode::Op::Laser { on: true, .. }))
            .count();
        assert_eq!(contours, 1000);
    }
}
