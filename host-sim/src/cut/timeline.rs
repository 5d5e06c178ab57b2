//! The program laid out in time: its spans (the tool's motions from rest to rest) and rests
//! (dwells, beam switches), each span timed by [`SpanLaw`] under one machine's
//! [`PathLimits`], and the tool's exact position, velocity, acceleration and jerk at any
//! instant.
//!
//! Where the tool rests (every plan, whichever machine): at a beam switch (`M3`/`M5`: the
//! pierce and the end of a cut happen at rest), at a dwell, where a rapid meets a feed move (the
//! beam changes there), after a `G61` block, and at the program's start and end. In between, a
//! span runs through its junctions at the speed [`PathLimits::junction`] allows.

use super::gcode::{Move, MoveKind, Op, Program};
use super::limits::{PathLimits, Scale};
use super::path::PathPoint;
use super::profile::{PathState, SpanLaw};

/// A run of moves from rest to rest.
#[derive(Clone, Debug, PartialEq)]
pub struct SpanDef {
    /// Indices into [`Layout::moves`].
    pub moves: Vec<usize>,
    /// Where each move starts along the span (mm).
    pub starts_mm: Vec<f64>,
    pub length_mm: f64,
    pub laser_on: bool,
    pub rapid: bool,
}

/// One step of the program in time.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Step {
    Span(usize),
    /// The tool at rest for `seconds` (0 for a beam switch), the beam as given.
    Rest {
        seconds: f64,
        laser_on: bool,
    },
}

/// The program's spans and steps (independent of any machine).
#[derive(Clone, Debug, PartialEq)]
pub struct Layout {
    pub moves: Vec<Move>,
    pub spans: Vec<SpanDef>,
    pub steps: Vec<Step>,
    pub start_mm: [f64; 2],
}

impl Layout {
    /// Splits `program` into spans at every place the tool must rest (module doc).
    pub fn new(program: &Program) -> Layout {
        let mut moves = Vec::new();
        let mut spans: Vec<SpanDef> = Vec::new();
        let mut steps = Vec::new();
        let mut open = false;
        let mut laser = false;
        for op in &program.ops {
            match *op {
                Op::Move(m) => {
                    let joins = open
                        && spans.last().is_some_and(|s| {
                            let last = &moves[*s.moves.last().unwrap_or(&0)];
                            let last: &Move = last;
                            s.laser_on == m.laser_on
                                && s.rapid == matches!(m.kind, MoveKind::Rapid)
                                && !last.exact_stop
                        });
                    if !joins {
                        steps.push(Step::Span(spans.len()));
                        spans.push(SpanDef {
                            moves: Vec::new(),
                            starts_mm: Vec::new(),
                            length_mm: 0.0,
                            laser_on: m.laser_on,
                            rapid: matches!(m.kind, MoveKind::Rapid),
                        });
                        open = true;
                    }
                    let s = spans.last_mut().expect("a span was just opened");
                    s.moves.push(moves.len());
                    s.starts_mm.push(s.length_mm);
                    s.length_mm += m.segment.length_mm();
                    moves.push(m);
                }
                Op::Dwell { seconds, .. } => {
                    open = false;
                    steps.push(Step::Rest {
                        seconds,
                        laser_on: laser,
                    });
                }
                Op::Laser { on, .. } => {
                    open = false;
                    laser = on;
                    steps.push(Step::Rest {
                        seconds: 0.0,
                        laser_on: on,
                    });
                }
            }
        }
        Layout {
            moves,
            spans,
            steps,
            start_mm: program.start_mm,
        }
    }

    /// The time law of span `k` under `limits`, slowed by `scale`.
    pub fn law(&self, k: usize, limits: &PathLimits, scale: Scale) -> SpanLaw {
        let span = &self.spans[k];
        let segs: Vec<_> = span
            .moves
            .iter()
            .map(|&i| limits.segment(&self.moves[i].segment, self.moves[i].kind, scale))
            .collect();
        let caps: Vec<f64> = span
            .moves
            .windows(2)
            .map(|w| limits.junction(&self.moves[w[0]].segment, &self.moves[w[1]].segment))
            .collect();
        SpanLaw::plan(&segs, &caps)
    }

    /// The end point of the program.
    pub fn end_mm(&self) -> [f64; 2] {
        self.moves
            .last()
            .map_or(self.start_mm, |m| m.segment.end_mm())
    }
}

/// The tool at one instant.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ToolSample {
    pub position_mm: [f64; 2],
    pub velocity_mm_s: [f64; 2],
    pub accel_mm_s2: [f64; 2],
    pub jerk_mm_s3: [f64; 2],
    pub laser_on: bool,
    /// The move the tool is on (index into [`Layout::moves`]), or the last one it was on.
    pub move_index: Option<usize>,
}

/// A cursor for evaluating a [`Timeline`] in time order (O(1) per sample).
#[derive(Clone, Copy, Debug, Default)]
pub struct Cursor {
    item: usize,
    phase: usize,
    seg: usize,
}

#[derive(Clone, Debug, PartialEq)]
enum Kind {
    Span { span: usize, law: SpanLaw },
    Rest { laser_on: bool },
}

#[derive(Clone, Debug, PartialEq)]
struct Item {
    t0_s: f64,
    duration_s: f64,
    kind: Kind,
    /// Where the tool is at the item's start, and the last move before it.
    at_mm: [f64; 2],
    last_move: Option<usize>,
}

/// The program timed by one machine.
#[derive(Clone, Debug, PartialEq)]
pub struct Timeline {
    items: Vec<Item>,
    duration_s: f64,
}

impl Timeline {
    /// Lays `layout` out with each span's law (`laws[k]` for span `k`).
    pub fn new(layout: &Layout, laws: Vec<SpanLaw>) -> Timeline {
        let mut laws: Vec<Option<SpanLaw>> = laws.into_iter().map(Some).collect();
        let mut items = Vec::with_capacity(layout.steps.len());
        let (mut t, mut at, mut last) = (0.0, layout.start_mm, None);
        for step in &layout.steps {
            match *step {
                Step::Span(k) => {
                    let law = laws[k].take().unwrap_or_else(|| SpanLaw::plan(&[], &[]));
                    let d = law.duration_s();
                    items.push(Item {
                        t0_s: t,
                        duration_s: d,
                        kind: Kind::Span { span: k, law },
                        at_mm: at,
                        last_move: last,
                    });
                    t += d;
                    let span = &layout.spans[k];
                    if let Some(&i) = span.moves.last() {
                        at = layout.moves[i].segment.end_mm();
                        last = Some(i);
                    }
                }
                Step::Rest { seconds, laser_on } => {
                    items.push(Item {
                        t0_s: t,
                        duration_s: seconds,
                        kind: Kind::Rest { laser_on },
                        at_mm: at,
                        last_move: last,
                    });
                    t += seconds;
                }
            }
        }
        Timeline {
            items,
            duration_s: t,
        }
    }

    /// Duration (s).
    pub fn duration_s(&self) -> f64 {
        self.duration_s
    }

    /// The spans' start times (s) and durations, in program order of the spans.
    pub fn span_times_s(&self) -> Vec<(usize, f64, f64)> {
        self.items
            .iter()
            .filter_map(|it| match &it.kind {
                Kind::Span { span, .. } => Some((*span, it.t0_s, it.duration_s)),
                Kind::Rest { .. } => None,
            })
            .collect()
    }

    /// The tool at `t_s` (at rest at the start before 0 and at the end after the duration).
    pub fn at(&self, layout: &Layout, t_s: f64, c: &mut Cursor) -> ToolSample {
        let rest = |p: [f64; 2], laser_on: bool, m: Option<usize>| ToolSample {
            position_mm: p,
            velocity_mm_s: [0.0; 2],
            accel_mm_s2: [0.0; 2],
            jerk_mm_s3: [0.0; 2],
            laser_on,
            move_index: m,
        };
        if self.items.is_empty() || !(t_s > 0.0) {
            return rest(layout.start_mm, false, None);
        }
        if c.item >= self.items.len() || self.items[c.item].t0_s > t_s {
            *c = Cursor::default();
        }
        while c.item + 1 < self.items.len() && self.items[c.item + 1].t0_s <= t_s {
            c.item += 1;
            c.phase = 0;
            c.seg = 0;
        }
        let it = &self.items[c.item];
        // Past the item's end (the last item): at rest at its end.
        if t_s >= it.t0_s + it.duration_s {
            return match &it.kind {
                Kind::Rest { laser_on } => rest(it.at_mm, *laser_on, it.last_move),
                Kind::Span { span, .. } => {
                    let sp = &layout.spans[*span];
                    let m = sp.moves.last().copied();
                    let end = m.map_or(it.at_mm, |i| layout.moves[i].segment.end_mm());
                    rest(end, false, m)
                }
            };
        }
        match &it.kind {
            Kind::Rest { laser_on } => rest(it.at_mm, *laser_on, it.last_move),
            Kind::Span { span, law } => {
                let st: PathState = law.at(t_s - it.t0_s, &mut c.phase);
                let sp = &layout.spans[*span];
                if c.seg >= sp.moves.len() || sp.starts_mm[c.seg] > st.s_mm {
                    c.seg = 0;
                }
                while c.seg + 1 < sp.moves.len() && sp.starts_mm[c.seg + 1] <= st.s_mm {
                    c.seg += 1;
                }
                let i = sp.moves[c.seg];
                let m = &layout.moves[i];
                let p: PathPoint = m.segment.at(st.s_mm - sp.starts_mm[c.seg]);
                let (v, a, j) = p.motion(st.v_mm_s, st.a_mm_s2, st.j_mm_s3);
                ToolSample {
                    position_mm: p.position_mm,
                    velocity_mm_s: v,
                    accel_mm_s2: a,
                    jerk_mm_s3: j,
                    laser_on: sp.laser_on,
                    move_index: Some(i),
                }
            }
        }
    }
}

/// Every span's law under `limits` (each slowed by `scales[k]`, default none).
pub fn laws(layout: &Layout, limits: &PathLimits, scales: Option<&[Scale]>) -> Vec<SpanLaw> {
    (0..layout.spans.len())
        .map(|k| {
            let s = scales.map_or(Scale::default(), |s| s[k]);
            layout.law(k, limits, s)
        })
        .collect()
}
