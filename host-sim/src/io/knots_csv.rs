//! The knot file: a streamed trajectory as `host-sim link stream --file` sends it and `identify
//! --knots` / `diagnose --telemetry ... --knots` read it (`host_sim::link::parse_knots_csv`):
//! a header line, then `t_s,x_mm,y_mm,vx_mm_s,vy_mm_s` per knot, times from the stream's start
//! (the machine at rest where the stream begins, time 0, not a row).
//!
//! Written exactly: times to the microsecond the controller counts in, positions and velocities
//! as the f32 values streamed (shortest exact), so that a file read back is the knots streamed.

use link_protocol::Knot;
use std::fmt::Write as _;

/// The header line.
pub const HEADER: &str = "t_s,x_mm,y_mm,vx_mm_s,vy_mm_s";

/// The file's text.
pub fn knots_text(knots: &[Knot]) -> String {
    let mut s = String::with_capacity(48 * (knots.len() + 1));
    s.push_str(HEADER);
    s.push('\n');
    for k in knots {
        let _ = writeln!(
            s,
            "{}.{:06},{},{},{},{}",
            k.t_us / 1_000_000,
            k.t_us % 1_000_000,
            k.position_mm[0],
            k.position_mm[1],
            k.velocity_mm_s[0],
            k.velocity_mm_s[1]
        );
    }
    s
}
