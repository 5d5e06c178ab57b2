//! Part programs in: RS274 G-code as laser cutters write it, read into the moves, dwells and
//! beam switches of a [`Program`] (mm, s, absolute coordinates).
//!
//! # Why not the `gcode` crate
//! `gcode` 0.6 (the Rust G-code parser) was evaluated first. It does not fit a cutter's
//! controller: (1) its words are `f32`: 0.24 µm steps at 3 m, and an arc's radius check needs
//! the coordinates as written; (2) it groups words as "a command and its arguments", so in
//! `G90 G1 X10` the X belongs to G90, and a modal line `X20 Y5` is an "argument without a
//! command" reported through a callback: RS274 reads a line as one *block* whose words act in a
//! fixed order; (3) it is built to keep going past errors (callbacks, then skipped), where a
//! controller must stop at the first word it cannot execute and name it. The block reader below
//! is small (a letter, a number, comments) and keeps every value as written in `f64`.
//!
//! # What is read
//! Words (case-insensitive, spaces allowed between a letter and its number): `G0 G1 G2 G3`
//! (arcs by `I J` or `R`), `G4 P<s>` (dwell, the pierce), `G17`, `G20 G21` (inch, mm), `G90
//! G91` (absolute, incremental), `G90.1 G91.1` (arc centres absolute, incremental: default),
//! `G94` (feed per minute), `G40 G49 G80` (cancel compensations and cycles this machine has
//! none of), `G54` (the program's coordinates are the gantry's), `G61` (exact stop at every
//! block end), `G64` (continuous: the default; a `P` tolerance is accepted and the path is
//! still followed exactly), `M3 M4` (beam on), `M5` (off), `M7 M8 M9` (assist gas: no motion
//! effect), `M2 M30` (end), `F S N`, and `O` (program number). Comments: `( ... )` and from `;`
//! to the end of the line; `%` lines. Anything else (`Z`, `T`, `M6`, `G41`, `G93`, `M0`, ...) is
//! refused naming its line and word: a code the planner would skip could cut something else.
//!
//! Semantics (RS274/NGC): the words of a block act in the order feed, `S`, beam, gas, dwell,
//! plane, units, modes, motion, end; so `G1 X10 M5` switches the beam off *before* the move.
//! The beam is off during `G0` (rapids never cut, as in laser-mode controllers). Arcs: `I J`
//! offsets from the start (or absolute with `G90.1`); start and end radius must agree within
//! 5 µm or 0.1 % (else refused: the centre does not match the radius), the centre is then put
//! on the chord's bisector so both agree exactly; `R` > 0 the short way, < 0 the long way; `I
//! J` with the end at the start is a full circle. Every point of every move, arcs' bulges
//! included, must lie in the gantry's travel.

use super::path::Segment;
use crate::gantry_spec::GantrySpec;

/// Radius mismatch of an `I J` arc accepted (mm), and relative to the radius.
const ARC_RADIUS_TOL_MM: f64 = 0.005;
const ARC_RADIUS_TOL_REL: f64 = 1e-3;
/// Longest program accepted (bytes): a nest of thousands of parts is a few MB.
pub const MAX_PROGRAM_BYTES: usize = 64 << 20;

/// Why a program cannot be cut.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum ProgramError {
    /// A word of a line (1-based) cannot be executed.
    #[error("line {line}: '{word}': {message}")]
    At {
        line: usize,
        word: String,
        message: String,
    },
    /// The program as a whole (not text, no motion).
    #[error("{0}")]
    Whole(String),
}

fn at(line: usize, word: &str, message: impl Into<String>) -> ProgramError {
    ProgramError::At {
        line,
        word: word.trim().to_string(),
        message: message.into(),
    }
}

/// How a move is made.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum MoveKind {
    /// `G0`: as fast as the machine allows, beam off.
    Rapid,
    /// `G1`/`G2`/`G3` at this feed (mm/s).
    Feed { feed_mm_s: f64 },
}

/// One move of the program.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Move {
    /// Line of the block (1-based).
    pub line: usize,
    pub kind: MoveKind,
    /// The beam is on during the move.
    pub laser_on: bool,
    /// `G61`: the tool stops at the end of this move.
    pub exact_stop: bool,
    pub segment: Segment,
}

/// What the program does, in order.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Op {
    Move(Move),
    /// `G4`: the tool rests (s); the beam as it is.
    Dwell {
        line: usize,
        seconds: f64,
    },
    /// The beam switches (the tool at rest).
    Laser {
        line: usize,
        on: bool,
    },
}

/// A part program read and checked.
#[derive(Clone, Debug, PartialEq)]
pub struct Program {
    pub ops: Vec<Op>,
    /// Where the tool is when the program starts (the gantry's home, the micro centred).
    pub start_mm: [f64; 2],
    /// Lines read.
    pub lines: usize,
}

impl Program {
    /// The moves, in order.
    pub fn moves(&self) -> impl Iterator<Item = &Move> {
        self.ops.iter().filter_map(|o| match o {
            Op::Move(m) => Some(m),
            _ => None,
        })
    }
}

/// One word: its letter, value and the text it was read from.
#[derive(Clone, Debug)]
struct Word {
    letter: char,
    value: f64,
    text: String,
}

/// The words of one line, comments removed.
fn words(line_no: usize, raw: &str) -> Result<Vec<Word>, ProgramError> {
    // Comments: `( ... )` (not nested) and `;` to the end.
    let mut text = String::with_capacity(raw.len());
    let mut in_paren = false;
    for c in raw.chars() {
        match (in_paren, c) {
            (false, ';') => break,
            (false, '(') => in_paren = true,
            (true, ')') => in_paren = false,
            (true, '(') => return Err(at(line_no, raw, "a comment inside a comment")),
            (false, ')') => return Err(at(line_no, raw, "')' without '('")),
            (true, _) => {}
            (false, c) => text.push(c),
        }
    }
    if in_paren {
        return Err(at(line_no, raw, "a comment '(' not closed on its line"));
    }
    let t = text.trim();
    if t == "%" || t.is_empty() {
        return Ok(Vec::new());
    }
    let chars: Vec<char> = t.chars().collect();
    let mut out = Vec::new();
    let mut i = 0;
    while i < chars.len() {
        let c = chars[i];
        if c.is_whitespace() {
            i += 1;
            continue;
        }
        let start = i;
        if !c.is_ascii_alphabetic() {
            let rest: String = chars[i..].iter().take(12).collect();
            return Err(at(
                line_no,
                &rest,
                "not G-code: a word is a letter followed by a number",
            ));
        }
        i += 1;
        while i < chars.len() && chars[i] == ' ' {
            i += 1;
        }
        let num_start = i;
        if i < chars.len() && (chars[i] == '+' || chars[i] == '-') {
            i += 1;
        }
        let (mut digits, mut dot) = (0, 0);
        while i < chars.len() && (chars[i].is_ascii_digit() || chars[i] == '.') {
            if chars[i] == '.' {
                dot += 1;
            } else {
                digits += 1;
            }
            i += 1;
        }
        let word: String = chars[start..i].iter().collect::<String>();
        let number: String = chars[num_start..i].iter().collect();
        if digits == 0 || dot > 1 {
            let shown: String = chars[start..]
                .iter()
                .take_while(|c| !c.is_whitespace())
                .collect();
            return Err(at(
                line_no,
                &shown,
                "not G-code: a word is a letter followed by a number",
            ));
        }
        let value: f64 = number
            .parse()
            .map_err(|_| at(line_no, &word, "not a number"))?;
        if !value.is_finite() || value.abs() > 1e9 {
            return Err(at(line_no, &word, "not a finite number of a sane size"));
        }
        out.push(Word {
            letter: c.to_ascii_uppercase(),
            value,
            text: word.replace(' ', ""),
        });
    }
    Ok(out)
}

/// The modal state while reading.
struct State {
    pos_mm: [f64; 2],
    inch: bool,
    incremental: bool,
    arc_absolute: bool,
    motion: Option<u32>,
    feed_mm_s: Option<f64>,
    laser_on: bool,
    exact_stop: bool,
    ended: bool,
}

/// A G or M code as `10 × number` (so `G90.1` is 901).
fn code(w: &Word) -> Option<u32> {
    let v = w.value * 10.0;
    (v >= 0.0 && (v - v.round()).abs() < 1e-6).then_some(v.round() as u32)
}

/// Reads and checks a part program (see the module doc); `gantry` gives its travel and home.
pub fn parse_program(text: &str, gantry: &GantrySpec) -> Result<Program, ProgramError> {
    if text.len() > MAX_PROGRAM_BYTES {
        return Err(ProgramError::Whole(format!(
            "the program has {} bytes; at most {MAX_PROGRAM_BYTES} are read",
            text.len()
        )));
    }
    if text.contains('\0') {
        return Err(ProgramError::Whole(
            "not a G-code program: the file contains NUL bytes (a binary file?)".into(),
        ));
    }
    let mut st = State {
        pos_mm: gantry.home_mm,
        inch: false,
        incremental: false,
        arc_absolute: false,
        motion: None,
        feed_mm_s: None,
        laser_on: false,
        exact_stop: false,
        ended: false,
    };
    let mut ops = Vec::new();
    let mut lines = 0;
    for (k, raw) in text.lines().enumerate() {
        lines = k + 1;
        let ws = words(k + 1, raw)?;
        if ws.is_empty() {
            continue;
        }
        if st.ended {
            return Err(at(k + 1, raw, "a block after the program's end (M2/M30)"));
        }
        block(k + 1, &ws, &mut st, gantry, &mut ops)?;
    }
    if !ops.iter().any(|o| matches!(o, Op::Move(_))) {
        return Err(ProgramError::Whole(
            "not a part program: no move (G0, G1, G2, G3) in it".into(),
        ));
    }
    if st.laser_on {
        // The beam goes off at the end of the program, the tool at rest.
        ops.push(Op::Laser {
            line: lines,
            on: false,
        });
    }
    Ok(Program {
        ops,
        start_mm: gantry.home_mm,
        lines,
    })
}

/// Executes one block's words in the RS274/NGC order.
fn block(
    line: usize,
    ws: &[Word],
    st: &mut State,
    gantry: &GantrySpec,
    ops: &mut Vec<Op>,
) -> Result<(), ProgramError> {
    let mut g = Vec::new();
    let mut m = Vec::new();
    let mut axis: [Option<&Word>; 7] = [None; 7]; // X Y I J R F P
    let slot = |c: char| "XYIJRFP".find(c);
    for w in ws {
        match w.letter {
            'G' => g.push(w),
            'M' => m.push(w),
            'N' | 'O' | 'S' => {}
            c if slot(c).is_some() => {
                let s = slot(c).unwrap_or(0);
                if axis[s].is_some() {
                    return Err(at(line, &w.text, "the same letter twice in one block"));
                }
                axis[s] = Some(w);
            }
            'Z' => {
                return Err(at(
                    line,
                    &w.text,
                    "the machine is planar (x, y): Z is not supported",
                ))
            }
            _ => {
                return Err(at(
                    line,
                    &w.text,
                    "not supported by this machine (see the G-code this cutter reads)",
                ))
            }
        }
    }
    let [x, y, i, j, r, f, p] = axis;
    let scale = |v: f64, inch: bool| if inch { v * 25.4 } else { v };
    // Sort the G and M codes into their groups (two of one group in a block is an error).
    let mut motion_g: Option<(&Word, u32)> = None;
    let mut dwell = None;
    let mut modal: Vec<(&Word, u32)> = Vec::new();
    for w in &g {
        let c = code(w).ok_or_else(|| at(line, &w.text, "not a G code"))?;
        match c {
            0 | 10 | 20 | 30 => {
                if motion_g.is_some() {
                    return Err(at(line, &w.text, "two motion codes in one block"));
                }
                motion_g = Some((w, c / 10));
            }
            40 => dwell = Some(*w),
            170 | 200 | 210 | 400 | 490 | 540 | 610 | 640 | 800 | 900 | 910 | 901 | 911 | 940 => {
                modal.push((w, c))
            }
            _ => return Err(at(line, &w.text, "G code not supported by this machine")),
        }
    }
    let groups: [&[u32]; 5] = [&[200, 210], &[900, 910], &[901, 911], &[610, 640], &[170]];
    for grp in groups {
        if modal.iter().filter(|(_, c)| grp.contains(c)).count() > 1 {
            return Err(at(line, &modal[0].0.text, "two codes of one modal group"));
        }
    }
    let mut beam = None;
    let mut end = false;
    for w in &m {
        match code(w) {
            Some(30) | Some(40) => beam = beam.or(Some(true)),
            Some(50) => {
                if beam == Some(true) {
                    return Err(at(line, &w.text, "beam on and off in one block"));
                }
                beam = Some(false)
            }
            Some(70) | Some(80) | Some(90) => {}
            Some(20) | Some(300) => end = true,
            _ => return Err(at(line, &w.text, "M code not supported by this machine")),
        }
    }
    // F (feed per minute, in the block's units: G20/G21 of this block count).
    let inch = modal
        .iter()
        .find_map(|(_, c)| match c {
            200 => Some(true),
            210 => Some(false),
            _ => None,
        })
        .unwrap_or(st.inch);
    if let Some(f) = f {
        if !(f.value > 0.0) {
            return Err(at(
                line,
                &f.text,
                "a feed must be positive (a feed of zero never arrives)",
            ));
        }
        st.feed_mm_s = Some(scale(f.value, inch) / 60.0);
    }
    if let Some(on) = beam {
        if on != st.laser_on {
            ops.push(Op::Laser { line, on });
            st.laser_on = on;
        }
    }
    if let Some(w) = dwell {
        let p = p.ok_or_else(|| at(line, &w.text, "a dwell needs P (seconds)"))?;
        if !(p.value >= 0.0 && p.value <= 3600.0) {
            return Err(at(line, &p.text, "a dwell of 0 to 3600 s"));
        }
        if p.value > 0.0 {
            ops.push(Op::Dwell {
                line,
                seconds: p.value,
            });
        }
    } else if let Some(p) = p {
        if !modal.iter().any(|(_, c)| *c == 640) {
            return Err(at(line, &p.text, "P without G4 (dwell) or G64"));
        }
    }
    for (_, c) in &modal {
        match c {
            200 => st.inch = true,
            210 => st.inch = false,
            900 => st.incremental = false,
            910 => st.incremental = true,
            901 => st.arc_absolute = true,
            911 => st.arc_absolute = false,
            610 => st.exact_stop = true,
            640 => st.exact_stop = false,
            _ => {}
        }
    }
    if let Some((_, c)) = motion_g {
        st.motion = Some(c);
    }
    let has_axis = x.is_some() || y.is_some();
    let has_arc = i.is_some() || j.is_some() || r.is_some();
    if has_axis || has_arc {
        let mode = st.motion.ok_or_else(|| {
            at(
                line,
                x.or(y).or(i).or(j).or(r).map_or("", |w| &w.text),
                "a coordinate before any motion code (G0, G1, G2, G3)",
            )
        })?;
        let target = |w: Option<&Word>, k: usize| match w {
            None => st.pos_mm[k],
            Some(w) if st.incremental => st.pos_mm[k] + scale(w.value, st.inch),
            Some(w) => scale(w.value, st.inch),
        };
        let to = [target(x, 0), target(y, 1)];
        let first = x
            .or(y)
            .or(i)
            .or(j)
            .or(r)
            .map_or(String::new(), |w| w.text.clone());
        let segment = match mode {
            0 | 1 => {
                if has_arc {
                    return Err(at(line, &first, "I, J or R on a straight move"));
                }
                Segment::line(st.pos_mm, to)
            }
            _ => arc(line, &first, st, to, i, j, r, mode == 3)?,
        };
        check_travel(line, &first, &segment, gantry)?;
        let kind = if mode == 0 {
            MoveKind::Rapid
        } else {
            let feed_mm_s = st
                .feed_mm_s
                .ok_or_else(|| at(line, &first, "a feed move before any feed (F) is set"))?;
            MoveKind::Feed { feed_mm_s }
        };
        if segment.length_mm() > 0.0 {
            ops.push(Op::Move(Move {
                line,
                kind,
                laser_on: st.laser_on && mode != 0,
                exact_stop: st.exact_stop,
                segment,
            }));
        }
        st.pos_mm = to;
    }
    if end {
        st.ended = true;
    }
    Ok(())
}

/// The arc of a `G2`/`G3` block (see the module doc).
#[allow(clippy::too_many_arguments)] // the block's words, each a different one
fn arc(
    line: usize,
    first: &str,
    st: &State,
    to: [f64; 2],
    i: Option<&Word>,
    j: Option<&Word>,
    r: Option<&Word>,
    ccw: bool,
) -> Result<Segment, ProgramError> {
    let from = st.pos_mm;
    let scale = |v: f64| if st.inch { v * 25.4 } else { v };
    let chord = [to[0] - from[0], to[1] - from[1]];
    let d = chord[0].hypot(chord[1]);
    let centre = match (r, i.is_some() || j.is_some()) {
        (Some(w), true) => return Err(at(line, &w.text, "R and I/J in one arc")),
        (Some(w), false) => {
            let radius = scale(w.value);
            if d < 1e-9 {
                return Err(at(
                    line,
                    &w.text,
                    "an R arc needs an end point away from its start (a full circle needs I/J)",
                ));
            }
            if radius.abs() < d / 2.0 - ARC_RADIUS_TOL_MM {
                return Err(at(
                    line,
                    &w.text,
                    format!(
                        "radius {:.4} mm is shorter than half the chord ({:.4} mm)",
                        radius.abs(),
                        d / 2.0
                    ),
                ));
            }
            let h = (radius * radius - d * d / 4.0).max(0.0).sqrt();
            let n = [-chord[1] / d, chord[0] / d];
            // Short way: the centre left of the chord for G3, right for G2; R < 0 the long way.
            let side = if ccw { 1.0 } else { -1.0 } * radius.signum();
            let mid = [(from[0] + to[0]) / 2.0, (from[1] + to[1]) / 2.0];
            [mid[0] + side * h * n[0], mid[1] + side * h * n[1]]
        }
        (None, false) => return Err(at(line, first, "an arc needs I/J (its centre) or R")),
        (None, true) => {
            let off = [
                i.map_or(0.0, |w| scale(w.value)),
                j.map_or(0.0, |w| scale(w.value)),
            ];
            let c = if st.arc_absolute {
                [
                    i.map_or(from[0], |w| scale(w.value)),
                    j.map_or(from[1], |w| scale(w.value)),
                ]
            } else {
                [from[0] + off[0], from[1] + off[1]]
            };
            let r0 = (from[0] - c[0]).hypot(from[1] - c[1]);
            let r1 = (to[0] - c[0]).hypot(to[1] - c[1]);
            let word = i.or(j).map_or(first.to_string(), |w| w.text.clone());
            if r0 < 1e-6 {
                return Err(at(
                    line,
                    &word,
                    "the arc's centre is its start point (radius 0)",
                ));
            }
            if (r1 - r0).abs() > ARC_RADIUS_TOL_MM.max(ARC_RADIUS_TOL_REL * r0) {
                return Err(at(
                    line,
                    &word,
                    format!(
                        "the arc's centre does not match its radius: {r0:.4} mm from the start, {r1:.4} mm from the end"
                    ),
                ));
            }
            if d < 1e-9 {
                c
            } else {
                // Onto the chord's bisector: both radii then agree exactly.
                let mid = [(from[0] + to[0]) / 2.0, (from[1] + to[1]) / 2.0];
                let n = [-chord[1] / d, chord[0] / d];
                let h = (c[0] - mid[0]) * n[0] + (c[1] - mid[1]) * n[1];
                [mid[0] + h * n[0], mid[1] + h * n[1]]
            }
        }
    };
    Segment::arc(from, to, centre, ccw)
        .ok_or_else(|| at(line, first, "the arc cannot be built (degenerate)"))
}

/// Every point of `s` in the gantry's travel.
fn check_travel(
    line: usize,
    word: &str,
    s: &Segment,
    gantry: &GantrySpec,
) -> Result<(), ProgramError> {
    let (lo, hi) = s.bounds_mm();
    let tol = 1e-9;
    let (tx, ty) = (gantry.travel_x_mm, gantry.travel_y_mm);
    if lo[0] < tx[0] - tol || hi[0] > tx[1] + tol || lo[1] < ty[0] - tol || hi[1] > ty[1] + tol {
        let end = s.end_mm();
        return Err(at(
            line,
            word,
            format!(
                "the move to ({:.3}, {:.3}) mm leaves the gantry's travel x [{}, {}], y [{}, {}] mm (it spans x [{:.3}, {:.3}], y [{:.3}, {:.3}])",
                end[0], end[1], tx[0], tx[1], ty[0], ty[1], lo[0], hi[0], lo[1], hi[1]
            ),
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn gantry() -> GantrySpec {
        GantrySpec::paper()
    }

    fn read(text: &str) -> Result<Program, ProgramError> {
        parse_program(text, &gantry())
    }

    fn refused(text: &str, line: usize, word: &str, want: &str) {
        match read(text) {
            Err(ProgramError::At {
                line: l,
                word: w,
                message,
            }) => {
                assert_eq!((l, w.as_str()), (line, word), "{message}");
                assert!(message.contains(want), "'{message}' lacks '{want}'");
            }
            other => panic!("{text:?}: {other:?}"),
        }
    }

    #[test]
    fn a_laser_program_reads_into_moves_dwells_and_beam_switches() {
        let p = read(
            "%\n(plate) G21 G90 G17\nG0 X100 Y100 ; to the pierce\nM3 S1000\nG4 P0.2\n\
             G1 X110 F6000\nG3 X100 Y110 I-10 J0\nG2 X90 Y100 R10\nM5\nG91 G0 X10\ng1x5y5\nM30\n",
        )
        .unwrap();
        let kinds: Vec<String> = p
            .ops
            .iter()
            .map(|o| match o {
                Op::Move(m) => format!("{:?}{}", m.kind, if m.laser_on { "*" } else { "" }),
                Op::Dwell { seconds, .. } => format!("dwell {seconds}"),
                Op::Laser { on, .. } => format!("laser {on}"),
            })
            .collect();
        assert_eq!(
            kinds,
            [
                "Rapid",
                "laser true",
                "dwell 0.2",
                "Feed { feed_mm_s: 100.0 }*",
                "Feed { feed_mm_s: 100.0 }*",
                "Feed { feed_mm_s: 100.0 }*",
                "laser false",
                "Rapid",
                "Feed { feed_mm_s: 100.0 }",
            ]
        );
        let moves: Vec<&Move> = p.moves().collect();
        assert_eq!(moves[2].segment.end_mm(), [100.0, 110.0]);
        assert!((moves[2].segment.length_mm() - 0.5 * std::f64::consts::PI * 10.0).abs() < 1e-9);
        // G2 R10 from (100, 110) to (90, 100): the short way (a quarter), clockwise.
        assert!((moves[3].segment.length_mm() - 0.5 * std::f64::consts::PI * 10.0).abs() < 1e-9);
        assert_eq!(moves[4].segment.end_mm(), [100.0, 100.0]);
        assert_eq!(moves[5].segment.end_mm(), [105.0, 105.0]);
        assert_eq!(moves[3].line, 8);
    }

    #[test]
    fn inches_full_circles_and_the_block_order() {
        let p = read("G20 G0 X1 Y1\nM3\nG2 F60 I0.5\nG1 X2 M5\n").unwrap();
        let m: Vec<&Move> = p.moves().collect();
        assert_eq!(m[0].segment.end_mm(), [25.4, 25.4]);
        assert!((m[1].segment.length_mm() - std::f64::consts::PI * 25.4).abs() < 1e-9);
        assert_eq!(m[1].kind, MoveKind::Feed { feed_mm_s: 25.4 });
        // M5 acts before the motion of its block.
        assert!(m[1].laser_on && !m[2].laser_on);
    }

    #[test]
    fn bad_programs_are_refused_naming_the_line_and_the_word() {
        refused("G0 X10\nG1 X20 F0\n", 2, "F0", "feed");
        refused("G0 X10\nG1 X20 F-5\n", 2, "F-5", "feed");
        refused(
            "G0 X10 Y10\nG1 F100 X20\nG2 X40 Y10 I5 J0\n",
            3,
            "I5",
            "does not match its radius",
        );
        refused(
            "G0 X10 Y10\nG1 X1600 F100\n",
            2,
            "X1600",
            "leaves the gantry's travel",
        );
        refused("hello world\n", 1, "hello", "not G-code");
        refused("G0 X10\nG0 Z5\n", 2, "Z5", "planar");
        refused("G0 X10\nM6 T1\n", 2, "T1", "not supported");
        refused("G0 X10\nM6\n", 2, "M6", "not supported");
        refused("G0 X10\nG41 X5\n", 2, "G41", "not supported");
        refused("G0 X10\nG1 X5\n", 2, "X5", "feed");
        refused("X5\n", 1, "X5", "before any motion code");
        refused("G0 X10 (unclosed\n", 1, "G0 X10 (unclosed", "not closed");
        refused("G0 X1.2.3\n", 1, "X1.2.3", "letter followed by a number");
        refused("G0 X10 X20\n", 1, "X20", "twice");
        refused("G0 G1 X10\n", 1, "G1", "two motion codes");
        refused(
            "G0 X10\nG2 X20 Y20 R1\n",
            2,
            "R1",
            "shorter than half the chord",
        );
        refused(
            "G0 X10 Y10\nM30\nG0 X20\n",
            3,
            "G0 X20",
            "after the program's end",
        );
        // A circle whose bulge leaves the travel, though its ends are inside.
        refused(
            "G0 X5 Y100\nG1 F100\nG2 I-10\n",
            3,
            "I-10",
            "leaves the gantry's travel",
        );
        assert!(matches!(
            read("(nothing)\n; at all\n"),
            Err(ProgramError::Whole(_))
        ));
        assert!(matches!(read("G0 X1\0\n"), Err(ProgramError::Whole(_))));
    }
}
