//! The machine record: what the controller must know of the machine it drives, in one value
//! with one canonical byte encoding.
//!
//! A record holds the machine's name, its nominal hidden robot (links, bases, encoder offsets,
//! working mode), the encoders' counting direction, its workspace polygon and stop margin, the
//! home position, and the plausibility limits a calibration image is judged against
//! ([`PlausibilityLimits`]). The host tools build it from the machine file
//! (`host_sim::machine_spec::MachineSpec::record`); the calibration image carries it as its
//! `HRMC` block (`crate::grid`), so the controller and the tools can never disagree about
//! which machine an image is for.
//!
//! # Encoding (version 1, little-endian, [`ENCODED_LEN`] bytes, no padding)
//! | offset | size | field |
//! |---:|---:|---|
//! | 0 | 16 | name: 1..=16 printable ASCII bytes, then zeros |
//! | 16 | 4 | flags: bits 0-2 working mode (as the image header), bit 3 encoder 1 counts negative, bit 4 encoder 2; others 0 |
//! | 20 | 10×4 | f32 nominal `a, b, c, d` (mm), `a0_x, a0_y` (mm), `b0_x, b0_y` (mm, relative to A0), `offset_1, offset_2` (rad) |
//! | 60 | 2 | workspace vertex count `n` (3..=16) |
//! | 62 | 2 | reserved, 0 |
//! | 64 | 16×8 | f32 pairs `(x_mm, y_mm)`: the workspace, counter-clockwise, starting at the vertex of lowest y (then lowest x); unused slots 0 |
//! | 192 | 4 | f32 stop margin (mm, ≥ 0) |
//! | 196 | 2×4 | f32 home position (mm), inside the workspace |
//! | 204 | 5×4 | f32 limits: same-machine tolerance (mm), node correction (mm), correction slope (mm/mm), backlash (rad), dynamics factor |
//! | 224 | 10×4 | f32 nominal dynamics: `I1, I2, m_C, J3, J4, fv1, fv2, fc1, fc2`, Coulomb speed |
//!
//! Every field has one encoding (unused slots and reserved bits zero, the polygon's starting
//! vertex fixed), so equal records encode to equal bytes.
//!
//! # The digest: which machine this is
//! [`MachineRecord::digest`] is the CRC-32C of bytes 16..192: working mode, encoder convention,
//! nominal model and workspace polygon: the machine's geometry. Two machine files with the same
//! geometry are the same machine whatever their names, stop margins, home positions and limits
//! (settings, not geometry). Cost: one CRC over 176 bytes.
//!
//! ```
//! use kinematics_core::machine::record::ENCODED_LEN;
//! use kinematics_core::machine::{MachineName, MachineRecord};
//!
//! let paper = MachineRecord::paper();
//! let mut bytes = [0u8; ENCODED_LEN];
//! paper.encode(&mut bytes).unwrap();
//! assert_eq!(MachineRecord::parse(&bytes), Ok(paper));
//! // Another name and tighter limits: the same machine.
//! let mut cell = paper;
//! cell.name = MachineName::new("cell-3").unwrap();
//! cell.limits.same_machine_tolerance_mm = 1.0;
//! assert_eq!(cell.digest(), paper.digest());
//! // A link 2 mm longer: another machine.
//! let mut longer = paper;
//! longer.nominal.b_mm = 152.0;
//! assert_ne!(longer.digest(), paper.digest());
//! // A corrupt record is refused, never read.
//! bytes[16] ^= 0x80; // a flag bit version 1 does not define
//! assert!(MachineRecord::parse(&bytes).is_err());
//! ```

use crate::backlash::MAX_BACKLASH_RAD;
use crate::dynamics::{FiveBarDynamics, PARAMETERS};
use crate::le_bytes::{f32_at, put_f32, put_u16, put_u32, u16_at, u32_at};
use crate::model::{FiveBar, ModelError, WorkingMode};
use crate::workspace::{ConvexWorkspace, WorkspaceLimits, MAX_WORKSPACE_VERTICES};

/// Bytes of a machine name.
pub const NAME_LEN: usize = 16;
/// Bytes of an encoded record.
pub const ENCODED_LEN: usize = 264;
/// The bytes the digest covers (geometry only).
const DIGEST_RANGE: core::ops::Range<usize> = 16..192;

/// The default same-machine tolerance (mm): see [`PlausibilityLimits`].
pub const DEFAULT_SAME_MACHINE_TOLERANCE_MM: f32 = 3.0;
/// The default largest node correction, at the tool (mm).
pub const DEFAULT_MAX_NODE_CORRECTION_MM: f32 = 3.0;
/// The default largest slope of the correction between neighbouring nodes (mm per mm).
pub const DEFAULT_MAX_CORRECTION_SLOPE: f32 = 0.05;
/// The default largest backlash per drive (rad).
pub const DEFAULT_MAX_BACKLASH_RAD: f32 = 1.0e-3;
/// The default dynamics factor.
pub const DEFAULT_DYNAMICS_FACTOR: f32 = 4.0;

/// The ranges a limit may be set in (a record outside them is refused: a limit that wide
/// checks nothing). `(name, lowest exclusive, highest inclusive)`.
pub const LIMIT_RANGES: [(&str, f32, f32); 5] = [
    ("same_machine_tolerance_mm", 0.0, 20.0),
    ("max_node_correction_mm", 0.0, 20.0),
    ("max_correction_slope", 0.0, 0.5),
    ("max_backlash_rad", 0.0, MAX_BACKLASH_RAD as f32),
    ("dynamics_factor", 1.0, 20.0),
];

/// Why a record was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum RecordError {
    /// Not [`ENCODED_LEN`] bytes (`parse`), or a buffer too small (`encode`).
    Length,
    /// The name is empty, longer than [`NAME_LEN`], or holds a byte that is not printable
    /// ASCII (or non-zero bytes after its end).
    Name,
    /// Flag bits or reserved bytes that version 1 does not define, or unused vertex slots
    /// that are not zero.
    Reserved,
    /// An encoder sign that is not +1 or −1.
    EncoderSign,
    /// The nominal model is not a valid five-bar.
    Model(ModelError),
    /// The workspace is not a convex counter-clockwise polygon of 3..=16 vertices, or its stop
    /// margin is negative or not finite.
    Workspace,
    /// The home position is not finite or outside the workspace.
    Home,
    /// A limit outside its range ([`LIMIT_RANGES`]), by name.
    Limit(&'static str),
    /// The nominal dynamics do not validate, or their friction is not positive (the friction
    /// limit is a multiple of it).
    Dynamics,
}

impl core::fmt::Display for RecordError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            RecordError::Length => write!(f, "a machine record is {ENCODED_LEN} bytes"),
            RecordError::Name => {
                write!(f, "the machine name must be 1..={NAME_LEN} printable ASCII characters")
            }
            RecordError::Reserved => f.write_str("the machine record has reserved bits set"),
            RecordError::EncoderSign => f.write_str("an encoder sign is not +1 or -1"),
            RecordError::Model(e) => write!(f, "the machine's nominal model: {e}"),
            RecordError::Workspace => f.write_str(
                "the machine's workspace is not a convex counter-clockwise polygon with a non-negative stop margin",
            ),
            RecordError::Home => {
                f.write_str("the machine's home position is not inside its workspace")
            }
            RecordError::Limit(name) => {
                let (lo, hi) = LIMIT_RANGES
                    .iter()
                    .find(|r| r.0 == *name)
                    .map_or((0.0, 0.0), |r| (r.1, r.2));
                write!(f, "the machine's limit {name} is outside ({lo}, {hi}]")
            }
            RecordError::Dynamics => f.write_str(
                "the machine's nominal dynamics are invalid (every inertia and friction must be positive)",
            ),
        }
    }
}

impl core::error::Error for RecordError {}

/// A machine's name: 1..=[`NAME_LEN`] printable ASCII characters.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct MachineName([u8; NAME_LEN]);

impl MachineName {
    /// `name` if it is 1..=16 printable ASCII characters.
    pub fn new(name: &str) -> Result<Self, RecordError> {
        let b = name.as_bytes();
        if b.is_empty() || b.len() > NAME_LEN || !b.iter().all(|c| (0x20..=0x7e).contains(c)) {
            return Err(RecordError::Name);
        }
        let mut out = [0u8; NAME_LEN];
        out[..b.len()].copy_from_slice(b);
        Ok(MachineName(out))
    }

    fn from_bytes(b: &[u8]) -> Result<Self, RecordError> {
        let len = b.iter().position(|&c| c == 0).unwrap_or(b.len());
        if b[len..].iter().any(|&c| c != 0) {
            return Err(RecordError::Name);
        }
        Self::new(core::str::from_utf8(&b[..len]).map_err(|_| RecordError::Name)?)
    }

    /// The name.
    pub fn as_str(&self) -> &str {
        let len = self.0.iter().position(|&c| c == 0).unwrap_or(NAME_LEN);
        // Built from printable ASCII only (`new`), so always UTF-8.
        core::str::from_utf8(&self.0[..len]).unwrap_or("")
    }
}

impl core::fmt::Display for MachineName {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// How far a calibration image may stray from its machine and still be accepted
/// (`docs/reference/calibration-image.md` derives each default).
///
/// * `same_machine_tolerance_mm` (default 3 mm): the largest distance between the tool
///   positions of the image's model and of the nominal over the workspace, after the best rigid
///   frame. A built machine is within about 1.5 mm of its drawing before calibration (the
///   paper's machine: 1.34 mm); another design is centimetres off; the instrument's frame
///   (translation, rotation) is free.
/// * `max_node_correction_mm` (3 mm): the largest tool displacement a node's correction may
///   make. The grid corrects what the model leaves, at most what separates the machine from its
///   drawing.
/// * `max_correction_slope` (0.05): the largest change of that displacement between
///   neighbouring nodes per millimetre between them: across the grid the commanded joint motion
///   differs from the model's by at most 5 % of the tool's, so no move sees a step.
/// * `max_backlash_rad` (1 mrad per drive): a play that moves a 150 mm lever's end by 0.15 mm
///   is a worn drive to repair, not one to compensate.
/// * `dynamics_factor` (4) and `nominal_dynamics`: an image's dynamics must give every joint
///   motion a kinetic energy within this factor of the nominal's at every workspace point (the
///   generalised eigenvalues of the two mass matrices), with a positive-definite mass matrix;
///   friction at most the factor times the nominal's, the Coulomb speed within the factor of it.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PlausibilityLimits {
    /// Largest tool-position difference from the nominal over the workspace (mm).
    pub same_machine_tolerance_mm: f32,
    /// Largest tool displacement of a node's correction (mm).
    pub max_node_correction_mm: f32,
    /// Largest change of the correction's tool displacement between neighbours per mm.
    pub max_correction_slope: f32,
    /// Largest lost motion per drive (rad).
    pub max_backlash_rad: f32,
    /// How far (a factor either way) an image's dynamics may be from `nominal_dynamics`.
    pub dynamics_factor: f32,
    /// The design's dynamics: what an identification should find.
    pub nominal_dynamics: FiveBarDynamics<f32>,
}

impl PlausibilityLimits {
    /// The default limits around the design's `nominal_dynamics`.
    pub fn with_nominal_dynamics(nominal_dynamics: FiveBarDynamics<f32>) -> Self {
        PlausibilityLimits {
            same_machine_tolerance_mm: DEFAULT_SAME_MACHINE_TOLERANCE_MM,
            max_node_correction_mm: DEFAULT_MAX_NODE_CORRECTION_MM,
            max_correction_slope: DEFAULT_MAX_CORRECTION_SLOPE,
            max_backlash_rad: DEFAULT_MAX_BACKLASH_RAD,
            dynamics_factor: DEFAULT_DYNAMICS_FACTOR,
            nominal_dynamics,
        }
    }

    fn scalars(&self) -> [f32; 5] {
        [
            self.same_machine_tolerance_mm,
            self.max_node_correction_mm,
            self.max_correction_slope,
            self.max_backlash_rad,
            self.dynamics_factor,
        ]
    }

    /// Every limit in its range, the nominal dynamics valid with positive friction.
    pub fn validate(&self) -> Result<(), RecordError> {
        for (v, (name, lo, hi)) in self.scalars().iter().zip(LIMIT_RANGES) {
            if !(*v > lo && *v <= hi) {
                return Err(RecordError::Limit(name));
            }
        }
        let d = &self.nominal_dynamics;
        d.validate().map_err(|_| RecordError::Dynamics)?;
        let friction = [d.viscous_nm_s_per_rad, d.coulomb_nm];
        if !friction.iter().flatten().all(|v| *v > 0.0) {
            return Err(RecordError::Dynamics);
        }
        Ok(())
    }
}

/// The machine the controller drives (module doc).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct MachineRecord {
    /// Its name (not part of the digest).
    pub name: MachineName,
    /// The nominal hidden robot, working mode and encoder offsets included.
    pub nominal: FiveBar<f32>,
    /// Counting direction of each encoder: geometric angle = sign · encoder angle + offset.
    pub encoder_sign: [i8; 2],
    /// Where it may be commanded, and how far inside a controlled stop ends.
    pub workspace: WorkspaceLimits,
    /// Where homing ends (mm), inside the workspace.
    pub home_mm: [f32; 2],
    /// What a calibration image is judged against.
    pub limits: PlausibilityLimits,
}

impl MachineRecord {
    /// The paper's machine (`crate::paper`): the nominal five-bar, the Table I rectangle with
    /// its 0.1 mm stop margin, home at its centre, the default limits around the design's
    /// dynamics.
    pub fn paper() -> Self {
        use crate::paper;
        let x = paper::WORKSPACE_X_MM.map(|v| v as f32);
        let y = paper::WORKSPACE_Y_MM.map(|v| v as f32);
        MachineRecord {
            name: MachineName(*b"paper\0\0\0\0\0\0\0\0\0\0\0"),
            nominal: paper::nominal(),
            encoder_sign: [1, 1],
            workspace: WorkspaceLimits {
                region: ConvexWorkspace::rectangle_unchecked(x, y),
                stop_margin_mm: paper::STOP_MARGIN_MM as f32,
            },
            home_mm: paper::HOME_MM.map(|v| v as f32),
            limits: PlausibilityLimits::with_nominal_dynamics(paper::nominal_dynamics()),
        }
    }

    /// Checks every field (see [`RecordError`]).
    pub fn validate(&self) -> Result<(), RecordError> {
        self.nominal.validate().map_err(RecordError::Model)?;
        if !self.encoder_sign.iter().all(|s| *s == 1 || *s == -1) {
            return Err(RecordError::EncoderSign);
        }
        let m = self.workspace.stop_margin_mm;
        if !(m.is_finite() && m >= 0.0) {
            return Err(RecordError::Workspace);
        }
        if !self.workspace.region.contains(self.home_mm, 0.0) {
            return Err(RecordError::Home);
        }
        self.limits.validate()
    }

    /// Writes the canonical encoding (module doc) into `out[..ENCODED_LEN]`; refuses a record
    /// that does not validate.
    pub fn encode(&self, out: &mut [u8]) -> Result<(), RecordError> {
        self.validate()?;
        let out = out.get_mut(..ENCODED_LEN).ok_or(RecordError::Length)?;
        self.write_geometry(out);
        out[..NAME_LEN].copy_from_slice(&self.name.0);
        put_f32(out, 192, self.workspace.stop_margin_mm);
        put_f32(out, 196, self.home_mm[0]);
        put_f32(out, 200, self.home_mm[1]);
        for (k, v) in self.limits.scalars().iter().enumerate() {
            put_f32(out, 204 + 4 * k, *v);
        }
        let d = &self.limits.nominal_dynamics;
        for (k, v) in d.to_array().iter().enumerate() {
            put_f32(out, 224 + 4 * k, *v);
        }
        put_f32(out, 224 + 4 * PARAMETERS, d.coulomb_speed_rad_s);
        Ok(())
    }

    /// The geometry's bytes (16..192 of the encoding; the rest of `out` zeroed).
    fn write_geometry(&self, out: &mut [u8]) {
        out.fill(0);
        let negative = |k: usize| u32::from(self.encoder_sign[k] < 0) << (3 + k);
        put_u32(
            out,
            16,
            self.nominal.mode.to_flags() | negative(0) | negative(1),
        );
        let m = &self.nominal;
        let model = [
            m.a_mm,
            m.b_mm,
            m.c_mm,
            m.d_mm,
            m.base_a0_mm[0],
            m.base_a0_mm[1],
            m.base_b0_mm[0],
            m.base_b0_mm[1],
            m.encoder_offset_rad[0],
            m.encoder_offset_rad[1],
        ];
        for (k, v) in model.iter().enumerate() {
            put_f32(out, 20 + 4 * k, *v);
        }
        let v = self.workspace.region.vertices_mm();
        put_u16(out, 60, v.len() as u16);
        let first = canonical_start(v);
        for k in 0..v.len() {
            let p = v[(first + k) % v.len()];
            put_f32(out, 64 + 8 * k, p[0]);
            put_f32(out, 68 + 8 * k, p[1]);
        }
    }

    /// Reads a record from its canonical encoding (exactly [`ENCODED_LEN`] bytes) and
    /// validates it.
    pub fn parse(bytes: &[u8]) -> Result<Self, RecordError> {
        if bytes.len() != ENCODED_LEN {
            return Err(RecordError::Length);
        }
        let name = MachineName::from_bytes(&bytes[..NAME_LEN])?;
        let flags = u32_at(bytes, 16);
        if flags & !0b1_1111 != 0 || u16_at(bytes, 62) != 0 {
            return Err(RecordError::Reserved);
        }
        let sign = |k: u32| if flags & (1 << (3 + k)) != 0 { -1 } else { 1 };
        let p = |k: usize| f32_at(bytes, 20 + 4 * k);
        let nominal = FiveBar {
            a_mm: p(0),
            b_mm: p(1),
            c_mm: p(2),
            d_mm: p(3),
            base_a0_mm: [p(4), p(5)],
            base_b0_mm: [p(6), p(7)],
            encoder_offset_rad: [p(8), p(9)],
            mode: WorkingMode::from_flags(flags),
        };
        let n = u16_at(bytes, 60) as usize;
        if !(3..=MAX_WORKSPACE_VERTICES).contains(&n) {
            return Err(RecordError::Workspace);
        }
        let mut v = [[0.0f32; 2]; MAX_WORKSPACE_VERTICES];
        for (k, q) in v.iter_mut().enumerate() {
            let at = 64 + 8 * k;
            if k >= n && (u32_at(bytes, at) != 0 || u32_at(bytes, at + 4) != 0) {
                return Err(RecordError::Reserved);
            }
            *q = [f32_at(bytes, at), f32_at(bytes, at + 4)];
        }
        let region = ConvexWorkspace::new(&v[..n]).map_err(|_| RecordError::Workspace)?;
        if canonical_start(region.vertices_mm()) != 0 {
            return Err(RecordError::Reserved);
        }
        let mut d = [0.0f32; PARAMETERS];
        for (k, x) in d.iter_mut().enumerate() {
            *x = f32_at(bytes, 224 + 4 * k);
        }
        let record = MachineRecord {
            name,
            nominal,
            encoder_sign: [sign(0), sign(1)],
            workspace: WorkspaceLimits {
                region,
                stop_margin_mm: f32_at(bytes, 192),
            },
            home_mm: [f32_at(bytes, 196), f32_at(bytes, 200)],
            limits: PlausibilityLimits {
                same_machine_tolerance_mm: f32_at(bytes, 204),
                max_node_correction_mm: f32_at(bytes, 208),
                max_correction_slope: f32_at(bytes, 212),
                max_backlash_rad: f32_at(bytes, 216),
                dynamics_factor: f32_at(bytes, 220),
                nominal_dynamics: FiveBarDynamics::from_array(
                    d,
                    f32_at(bytes, 224 + 4 * PARAMETERS),
                ),
            },
        };
        record.validate()?;
        Ok(record)
    }

    /// The machine's identity: CRC-32C of its geometry's canonical encoding (module doc).
    pub fn digest(&self) -> u32 {
        let mut b = [0u8; ENCODED_LEN];
        self.write_geometry(&mut b);
        CRC32C.checksum(&b[DIGEST_RANGE])
    }
}

/// CRC-32C (Castagnoli), the link's calibration-id CRC.
const CRC32C: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISCSI);

/// Index of the vertex the canonical encoding starts at: lowest y, then lowest x.
fn canonical_start(v: &[[f32; 2]]) -> usize {
    let mut best = 0;
    for (k, p) in v.iter().enumerate() {
        let b = v[best];
        if p[1] < b[1] || (p[1] == b[1] && p[0] < b[0]) {
            best = k;
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_paper_record_round_trips_and_its_digest_is_its_geometry() {
        let r = MachineRecord::paper();
        assert_eq!(r.validate(), Ok(()));
        let mut b = [0u8; ENCODED_LEN];
        r.encode(&mut b).unwrap();
        assert_eq!(MachineRecord::parse(&b), Ok(r));
        assert_eq!(r.name.as_str(), "paper");
        // Name, limits, margin and home are not the machine's identity...
        let mut other = r;
        other.name = MachineName::new("paper-2").unwrap();
        other.limits.same_machine_tolerance_mm = 1.0;
        other.workspace.stop_margin_mm = 0.3;
        other.home_mm = [200.0, 10.0];
        assert_eq!(other.digest(), r.digest());
        // ...the geometry is, every part of it.
        let mut g = r;
        g.nominal.b_mm = 150.5;
        assert_ne!(g.digest(), r.digest());
        let mut g = r;
        g.encoder_sign = [1, -1];
        assert_ne!(g.digest(), r.digest());
        let mut g = r;
        g.nominal.mode.assembly = crate::Branch::Negative;
        assert_ne!(g.digest(), r.digest());
        let mut g = r;
        g.workspace.region = ConvexWorkspace::rectangle([162.132, 262.132], [-75.0, 74.0]).unwrap();
        assert_ne!(g.digest(), r.digest());
    }

    #[test]
    fn the_polygon_is_encoded_from_its_lowest_vertex() {
        let mut r = MachineRecord::paper();
        let v = [
            [262.132f32, 75.0],
            [162.132, 75.0],
            [162.132, -75.0],
            [262.132, -75.0],
        ];
        r.workspace.region = ConvexWorkspace::new(&v).unwrap();
        assert_eq!(r.digest(), MachineRecord::paper().digest());
        let mut b = [0u8; ENCODED_LEN];
        r.encode(&mut b).unwrap();
        let back = MachineRecord::parse(&b).unwrap();
        assert_eq!(back.workspace.region.vertices_mm()[0], [162.132, -75.0]);
        // A record whose stored polygon does not start there has two encodings: refused.
        let mut bad = b;
        bad.copy_within(64..72, 120);
        bad.copy_within(72..96, 64);
        bad.copy_within(120..128, 88);
        assert_eq!(MachineRecord::parse(&bad), Err(RecordError::Reserved));
    }

    #[test]
    fn bad_records_are_refused_by_name() {
        let r = MachineRecord::paper();
        let mut b = [0u8; ENCODED_LEN];
        r.encode(&mut b).unwrap();
        assert_eq!(MachineRecord::parse(&b[..10]), Err(RecordError::Length));
        let edit = |at: usize, v: &[u8]| {
            let mut c = b;
            c[at..at + v.len()].copy_from_slice(v);
            MachineRecord::parse(&c)
        };
        assert_eq!(edit(0, &[0]), Err(RecordError::Name));
        assert_eq!(edit(6, b"x"), Err(RecordError::Name), "bytes after the end");
        assert_eq!(edit(1, &[0x07]), Err(RecordError::Name));
        assert_eq!(edit(16, &[0x27]), Err(RecordError::Reserved));
        assert_eq!(edit(62, &[1]), Err(RecordError::Reserved));
        assert_eq!(
            edit(100, &[1]),
            Err(RecordError::Reserved),
            "unused vertex slot"
        );
        assert_eq!(
            edit(20, &(-1.0f32).to_le_bytes()),
            Err(RecordError::Model(ModelError::NonPositiveLink))
        );
        assert_eq!(edit(60, &[2, 0]), Err(RecordError::Workspace));
        assert_eq!(
            edit(192, &(-0.1f32).to_le_bytes()),
            Err(RecordError::Workspace)
        );
        assert_eq!(edit(196, &(100.0f32).to_le_bytes()), Err(RecordError::Home));
        for (k, (name, lo, hi)) in LIMIT_RANGES.iter().enumerate() {
            assert_eq!(
                edit(204 + 4 * k, &lo.to_le_bytes()),
                Err(RecordError::Limit(name))
            );
            let above = f32::from_bits(hi.to_bits() + 1);
            assert_eq!(
                edit(204 + 4 * k, &above.to_le_bytes()),
                Err(RecordError::Limit(name))
            );
            assert!(
                edit(204 + 4 * k, &hi.to_le_bytes()).is_ok(),
                "{name} at its ceiling"
            );
            assert_eq!(
                edit(204 + 4 * k, &f32::NAN.to_le_bytes()),
                Err(RecordError::Limit(name))
            );
        }
        assert_eq!(
            edit(224, &(0.0f32).to_le_bytes()),
            Err(RecordError::Dynamics)
        );
        assert_eq!(
            edit(224 + 20, &(0.0f32).to_le_bytes()),
            Err(RecordError::Dynamics)
        );
        assert_eq!(MachineName::new(""), Err(RecordError::Name));
        assert_eq!(
            MachineName::new("seventeen-chars!!"),
            Err(RecordError::Name)
        );
        assert_eq!(
            MachineName::new("sixteen-chars!!!").unwrap().as_str(),
            "sixteen-chars!!!"
        );
        assert_eq!(MachineName::new("é"), Err(RecordError::Name));
    }
}
