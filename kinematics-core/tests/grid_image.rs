//! The flash image of the correction grid: round trip, every single bit flip rejected,
//! malformed headers rejected, interpolation exact on bilinear fields, edges, outside.

use kinematics_core::grid::{encode, CorrectionGrid, GridError, GridGeometry, HEADER_LEN};
use kinematics_core::FiveBar;

fn geometry() -> GridGeometry {
    GridGeometry {
        nx: 21,
        ny: 31,
        x0_mm: 162.132,
        y0_mm: -75.0,
        step_x_mm: 5.0,
        step_y_mm: 5.0,
    }
}

/// A bilinear field f(x, y) = c0 + c1 x + c2 y + c3 x y per motor: interpolation must be exact.
fn field(p: [f32; 2]) -> [f32; 2] {
    let (x, y) = ((p[0] - 200.0) as f64, p[1] as f64);
    [
        (1e-4 + 2e-6 * x - 3e-6 * y + 1e-8 * x * y) as f32,
        (-2e-4 - 1e-6 * x + 4e-6 * y - 2e-8 * x * y) as f32,
    ]
}

fn image() -> Vec<u8> {
    let g = geometry();
    let nodes: Vec<[f32; 2]> = (0..g.ny)
        .flat_map(|j| (0..g.nx).map(move |i| (i, j)))
        .map(|(i, j)| field(g.node_mm(i, j)))
        .collect();
    let mut buf = vec![0u8; g.image_len()];
    let n = encode(&mut buf, &g, &FiveBar::paper_nominal(), &nodes).unwrap();
    assert_eq!(n, buf.len());
    buf
}

#[test]
fn round_trip_and_exact_on_bilinear_field() {
    let img = image();
    let grid = CorrectionGrid::parse(&img).unwrap();
    assert_eq!(*grid.geometry(), geometry());
    assert_eq!(*grid.model(), FiveBar::paper_nominal());
    for k in 0..500 {
        let p = [
            162.132 + (k as f32 * 0.7919) % 100.0,
            -75.0 + (k as f32 * 1.3771) % 150.0,
        ];
        let got = grid.correction_rad(p).unwrap();
        let want = field(p);
        for m in 0..2 {
            assert!(
                (got[m] - want[m]).abs() < 2e-9,
                "{p:?}: {got:?} vs {want:?}"
            );
        }
    }
}

#[test]
fn nodes_edges_and_corners_take_the_node_values() {
    let img = image();
    let grid = CorrectionGrid::parse(&img).unwrap();
    let g = geometry();
    for (i, j) in [(0, 0), (20, 30), (0, 30), (20, 0), (7, 13)] {
        let p = g.node_mm(i, j);
        assert_eq!(grid.correction_rad(p).unwrap(), grid.node_rad(i, j));
    }
    // A node index past the end of the table reads as zero instead of panicking.
    assert_eq!(grid.node_rad(0, 31), [0.0; 2]);
    assert_eq!(grid.node_rad(u16::MAX, u16::MAX), [0.0; 2]);
    // On the edge x = x_max, halfway between two nodes: the mean of those two nodes.
    let mid = [
        g.node_mm(20, 4)[0],
        (g.node_mm(20, 4)[1] + g.node_mm(20, 5)[1]) / 2.0,
    ];
    let (a, b) = (grid.node_rad(20, 4), grid.node_rad(20, 5));
    let got = grid.correction_rad(mid).unwrap();
    assert!((got[0] - (a[0] + b[0]) / 2.0).abs() < 1e-10);
}

#[test]
fn outside_the_grid_is_refused_and_rounding_at_the_edge_is_not() {
    let img = image();
    let grid = CorrectionGrid::parse(&img).unwrap();
    assert_eq!(
        grid.correction_rad([162.0, 0.0]),
        Err(GridError::OutsideGrid)
    );
    assert_eq!(
        grid.correction_rad([200.0, 75.1]),
        Err(GridError::OutsideGrid)
    );
    assert_eq!(
        grid.correction_rad([f32::NAN, 0.0]),
        Err(GridError::OutsideGrid)
    );
    assert_eq!(
        grid.correction_rad([f32::INFINITY, 0.0]),
        Err(GridError::OutsideGrid)
    );
    // 0.1 µm outside the last node: float rounding of a boundary target, takes the edge value.
    assert!(grid.correction_rad([262.1321, 75.0]).is_ok());
}

/// The refusal is probed where the tolerance ends. The tolerance is 1e-4 of a cell
/// (`grid::EDGE_TOLERANCE_CELLS`), 0.5 µm for these 5 mm cells: it absorbs float rounding of a
/// target on the boundary, nothing more. At twice that (1 µm) outside each of the four edges a
/// point is refused; at half of it, it takes the edge value. The distances are the documented
/// figure, not read from the constant, so a widened tolerance fails here.
#[test]
fn refusal_starts_within_twice_the_edge_tolerance_on_every_edge() {
    const TOLERANCE_MM: f32 = 1.0e-4 * 5.0;
    let img = image();
    let grid = CorrectionGrid::parse(&img).unwrap();
    let g = geometry();
    assert_eq!((g.step_x_mm, g.step_y_mm), (5.0, 5.0));
    let (x_lo, x_hi) = (g.x0_mm, g.node_mm(g.nx - 1, 0)[0]);
    let (y_lo, y_hi) = (g.y0_mm, g.node_mm(0, g.ny - 1)[1]);
    let (x_mid, y_mid) = ((x_lo + x_hi) / 2.0, (y_lo + y_hi) / 2.0);
    let edges = [
        ([x_lo, y_mid], [-1.0, 0.0]),
        ([x_hi, y_mid], [1.0, 0.0]),
        ([x_mid, y_lo], [0.0, -1.0]),
        ([x_mid, y_hi], [0.0, 1.0]),
    ];
    for (edge, outward) in edges {
        let at = |k: f32| {
            [
                edge[0] + k * TOLERANCE_MM * outward[0],
                edge[1] + k * TOLERANCE_MM * outward[1],
            ]
        };
        assert_eq!(
            grid.correction_rad(at(2.0)),
            Err(GridError::OutsideGrid),
            "1 µm outside {edge:?}"
        );
        assert_eq!(
            grid.correction_rad(at(5.0)),
            Err(GridError::OutsideGrid),
            "2.5 µm outside {edge:?}"
        );
        let inside = grid
            .correction_rad(at(0.5))
            .unwrap_or_else(|e| panic!("{e} 0.25 µm outside {edge:?}"));
        // Taking the edge value: the same as on the edge itself, to f32 rounding.
        let on_edge = grid.correction_rad(edge).unwrap();
        for k in 0..2 {
            assert!(
                (inside[k] - on_edge[k]).abs() < 1e-9,
                "{inside:?} vs {on_edge:?}"
            );
        }
    }
}

#[test]
fn every_single_bit_flip_is_rejected() {
    let img = image();
    let mut flipped = img.clone();
    for byte in 0..img.len() {
        for bit in 0..8 {
            flipped[byte] ^= 1 << bit;
            assert!(
                CorrectionGrid::parse(&flipped).is_err(),
                "flip of byte {byte} bit {bit} accepted"
            );
            flipped[byte] ^= 1 << bit;
        }
    }
    assert!(CorrectionGrid::parse(&flipped).is_ok());
}

#[test]
fn trailing_flash_is_ignored_but_truncation_is_not() {
    let mut img = image();
    let len = img.len();
    img.extend(std::iter::repeat_n(0xFF, 4096));
    assert!(CorrectionGrid::parse(&img).is_ok());
    assert_eq!(
        CorrectionGrid::parse(&img[..len - 1]).unwrap_err(),
        GridError::Truncated
    );
    assert_eq!(
        CorrectionGrid::parse(&img[..10]).unwrap_err(),
        GridError::Truncated
    );
    assert_eq!(
        CorrectionGrid::parse(&[0xFF; 8192]).unwrap_err(),
        GridError::BadMagic
    );
    assert_eq!(
        CorrectionGrid::parse(&[]).unwrap_err(),
        GridError::Truncated
    );
}

/// Re-encodes with a tampered header and a *valid* CRC: the semantic checks must catch it.
fn with_valid_crc(mut img: Vec<u8>) -> Vec<u8> {
    let n = img.len();
    let crc = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC).checksum(&img[..n - 4]);
    img[n - 4..].copy_from_slice(&crc.to_le_bytes());
    img
}

#[test]
fn consistent_but_invalid_images_are_rejected() {
    let img = image();
    let mut v = img.clone();
    v[4] = 2;
    assert_eq!(
        CorrectionGrid::parse(&with_valid_crc(v)).unwrap_err(),
        GridError::UnsupportedVersion(2)
    );
    let mut v = img.clone();
    v[24..28].copy_from_slice(&(-5.0f32).to_le_bytes());
    assert_eq!(
        CorrectionGrid::parse(&with_valid_crc(v)).unwrap_err(),
        GridError::NonFinite
    );
    let mut v = img.clone();
    v[32..36].copy_from_slice(&0.0f32.to_le_bytes());
    assert_eq!(
        CorrectionGrid::parse(&with_valid_crc(v)).unwrap_err(),
        GridError::BadModel
    );
    let mut v = img.clone();
    v[HEADER_LEN..HEADER_LEN + 4].copy_from_slice(&f32::NAN.to_le_bytes());
    assert_eq!(
        CorrectionGrid::parse(&with_valid_crc(v)).unwrap_err(),
        GridError::NonFinite
    );
    let mut v = img.clone();
    v[12] |= 0x10;
    assert_eq!(
        CorrectionGrid::parse(&with_valid_crc(v)).unwrap_err(),
        GridError::BadHeader
    );
    let mut v = img;
    v[8..10].copy_from_slice(&1u16.to_le_bytes());
    assert_eq!(
        CorrectionGrid::parse(&with_valid_crc(v)).unwrap_err(),
        GridError::BadHeader
    );
}

#[test]
fn encode_refuses_bad_input() {
    let g = geometry();
    let mut buf = vec![0u8; g.image_len()];
    let m = FiveBar::paper_nominal();
    assert_eq!(
        encode(&mut buf, &g, &m, &[[0.0; 2]; 3]),
        Err(GridError::BadEncodeInput)
    );
    assert_eq!(
        encode(&mut buf[..100], &g, &m, &vec![[0.0; 2]; g.len()]),
        Err(GridError::BadEncodeInput)
    );
    let mut nodes = vec![[0.0f32; 2]; g.len()];
    nodes[5][1] = f32::NAN;
    assert_eq!(encode(&mut buf, &g, &m, &nodes), Err(GridError::NonFinite));
}

// ---------------------------------------------------------------------------------------------
// Extension blocks (grid.rs, "Extension blocks"): the workspace block and the chain.

use kinematics_core::grid::{
    append_workspace, image_crc, WorkspaceLimits, WORKSPACE_LEN, WORKSPACE_MAGIC,
};
use kinematics_core::ConvexWorkspace;

/// A hexagon inside the grid (the rectangle with two corners cut).
fn limits() -> WorkspaceLimits {
    let v = [
        [172.0, -75.0],
        [262.0, -75.0],
        [262.0, 65.0],
        [252.0, 75.0],
        [163.0, 75.0],
        [163.0, -66.0],
    ];
    WorkspaceLimits {
        region: ConvexWorkspace::new(&v).unwrap(),
        stop_margin_mm: 0.25,
    }
}

fn image_with_workspace() -> Vec<u8> {
    let mut img = image();
    let n = img.len();
    img.resize(n + WORKSPACE_LEN, 0xAA);
    assert_eq!(
        append_workspace(&mut img, n, n, &limits()),
        Ok(n + WORKSPACE_LEN)
    );
    img
}

#[test]
fn the_workspace_block_round_trips_and_a_version_1_reader_still_reads_the_grid() {
    let img = image_with_workspace();
    let grid = CorrectionGrid::parse(&img).unwrap();
    assert_eq!(grid.workspace(), Some(limits()));
    let v1 = image();
    assert_eq!(
        &img[..v1.len()],
        &v1[..],
        "the first image_len bytes are exactly the version-1 image"
    );
    assert_eq!(CorrectionGrid::parse(&v1).unwrap().workspace(), None);
    assert_eq!(
        CorrectionGrid::parse(&v1)
            .unwrap()
            .correction_rad([200.0, 10.0]),
        grid.correction_rad([200.0, 10.0])
    );
    // In a flash region: erased bytes end the chain.
    let mut region = img.clone();
    region.extend([0xFF; 4096]);
    assert_eq!(
        CorrectionGrid::parse(&region).unwrap().workspace(),
        Some(limits())
    );
    // Any other bytes that are no known magic end it too.
    let mut region = img.clone();
    region.extend(b"HRXX and then anything");
    assert_eq!(
        CorrectionGrid::parse(&region).unwrap().workspace(),
        Some(limits())
    );
}

#[test]
fn every_bit_flip_in_the_workspace_block_refuses_the_image() {
    let img = image_with_workspace();
    let start = geometry().image_len();
    // A flip in the magic makes the bytes "no known block" (the chain ends, no workspace);
    // every other flip must be caught.
    for byte in start + 4..img.len() {
        for bit in 0..8 {
            let mut v = img.clone();
            v[byte] ^= 1 << bit;
            assert_eq!(
                CorrectionGrid::parse(&v).unwrap_err(),
                GridError::BadWorkspace,
                "byte {byte} bit {bit}"
            );
        }
    }
    for byte in start..start + 4 {
        let mut v = img.clone();
        v[byte] ^= 0x40;
        assert_eq!(CorrectionGrid::parse(&v).unwrap().workspace(), None);
    }
    assert_eq!(
        CorrectionGrid::parse(&img[..img.len() - 1]).unwrap_err(),
        GridError::BadWorkspace,
        "truncated"
    );
    assert_eq!(
        CorrectionGrid::parse(&img[..start + 4]).unwrap_err(),
        GridError::BadWorkspace,
        "magic only"
    );
}

/// Rewrites the block's CRC after a payload edit: the checks behind the CRC must still refuse.
fn with_payload_edit(edit: impl FnOnce(&mut [u8])) -> Result<(), GridError> {
    let mut img = image_with_workspace();
    let start = geometry().image_len();
    edit(&mut img[start + 12..start + WORKSPACE_LEN - 4]);
    let crc = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC)
        .checksum(&img[start..start + WORKSPACE_LEN - 4]);
    img[start + WORKSPACE_LEN - 4..start + WORKSPACE_LEN].copy_from_slice(&crc.to_le_bytes());
    CorrectionGrid::parse(&img).map(|_| ())
}

#[test]
fn a_workspace_that_is_not_a_workspace_is_refused_even_with_a_valid_crc() {
    assert_eq!(with_payload_edit(|_| {}), Ok(()));
    let bad = GridError::BadWorkspace;
    // Vertex count 2 and 17; reserved bytes; a negative or NaN margin.
    assert_eq!(
        with_payload_edit(|p| p[0..2].copy_from_slice(&2u16.to_le_bytes())),
        Err(bad)
    );
    assert_eq!(
        with_payload_edit(|p| p[0..2].copy_from_slice(&17u16.to_le_bytes())),
        Err(bad)
    );
    assert_eq!(with_payload_edit(|p| p[2] = 1), Err(bad));
    assert_eq!(
        with_payload_edit(|p| p[4..8].copy_from_slice(&(-0.1f32).to_le_bytes())),
        Err(bad)
    );
    assert_eq!(
        with_payload_edit(|p| p[4..8].copy_from_slice(&f32::NAN.to_le_bytes())),
        Err(bad)
    );
    // A concave polygon (vertex 2 pulled inwards), a vertex outside the grid, junk in an unused slot.
    assert_eq!(
        with_payload_edit(|p| p[8 + 16..12 + 16].copy_from_slice(&200.0f32.to_le_bytes())),
        Err(bad)
    );
    assert_eq!(
        with_payload_edit(|p| p[8 + 8..12 + 8].copy_from_slice(&263.0f32.to_le_bytes())),
        Err(bad)
    );
    assert_eq!(with_payload_edit(|p| p[8 + 8 * 6] = 1), Err(bad));
}

#[test]
fn a_block_comes_at_most_once_and_belongs_to_its_image() {
    let img = image_with_workspace();
    let start = geometry().image_len();
    let block = img[start..].to_vec();
    // The same block twice: refused.
    let mut twice = img.clone();
    twice.extend_from_slice(&block);
    assert_eq!(
        CorrectionGrid::parse(&twice).unwrap_err(),
        GridError::BadWorkspace
    );
    // A block left behind by another image (one node changed, image CRC rewritten).
    let mut other = image();
    other[HEADER_LEN] ^= 1;
    let n = other.len();
    let crc = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC).checksum(&other[..n - 4]);
    other[n - 4..].copy_from_slice(&crc.to_le_bytes());
    other.extend_from_slice(&block);
    assert_eq!(
        CorrectionGrid::parse(&other).unwrap_err(),
        GridError::BadWorkspace
    );
    assert_eq!(
        image_crc(&img, start),
        Some(u32::from_le_bytes(
            img[start - 4..start].try_into().unwrap()
        ))
    );
    assert_eq!(&img[start..start + 4], &WORKSPACE_MAGIC);
}

#[test]
fn append_workspace_refuses_what_the_parser_would() {
    let mut img = image();
    let n = img.len();
    img.resize(n + WORKSPACE_LEN, 0);
    // Outside the grid's rectangle.
    let outside = WorkspaceLimits {
        region: ConvexWorkspace::rectangle([150.0, 250.0], [-70.0, 70.0]).unwrap(),
        stop_margin_mm: 0.1,
    };
    assert_eq!(
        append_workspace(&mut img, n, n, &outside),
        Err(GridError::BadWorkspace)
    );
    let negative = WorkspaceLimits {
        stop_margin_mm: -1.0,
        ..limits()
    };
    assert_eq!(
        append_workspace(&mut img, n, n, &negative),
        Err(GridError::BadWorkspace)
    );
    // Too small a buffer, a position inside the image, a corrupt image.
    assert_eq!(
        append_workspace(&mut img[..n + 10], n, n, &limits()),
        Err(GridError::BadEncodeInput)
    );
    assert_eq!(
        append_workspace(&mut img, n, n - 1, &limits()),
        Err(GridError::BadEncodeInput)
    );
    img[100] ^= 1;
    assert_eq!(
        append_workspace(&mut img, n, n, &limits()),
        Err(GridError::BadCrc)
    );
}

// ---------------------------------------------------------------------------------------------
// The dynamics block (grid.rs, "Extension blocks", `HRDY`).

fn dynamics() -> kinematics_core::FiveBarDynamics<f32> {
    kinematics_core::FiveBarDynamics {
        motor_inertia_kg_m2: [3.1e-3, 2.9e-3],
        tool_mass_kg: 0.11,
        distal_inertia_kg_m2: [-2.5e-4, -2.4e-4],
        viscous_nm_s_per_rad: [0.02, 0.021],
        coulomb_nm: [0.05, 0.049],
        coulomb_speed_rad_s: 0.01,
    }
}

fn image_with_dynamics() -> Vec<u8> {
    let g = geometry();
    let nodes: Vec<[f32; 2]> = (0..g.ny)
        .flat_map(|j| (0..g.nx).map(move |i| (i, j)))
        .map(|(i, j)| field(g.node_mm(i, j)))
        .collect();
    let mut buf = vec![0u8; g.image_len_with_dynamics()];
    let n = kinematics_core::grid::encode_with_dynamics(
        &mut buf,
        &g,
        &FiveBar::paper_nominal(),
        &nodes,
        &dynamics(),
    )
    .unwrap();
    assert_eq!(n, buf.len());
    buf
}

#[test]
fn the_dynamics_extension_round_trips_and_a_version_1_reader_still_reads_the_grid() {
    let img = image_with_dynamics();
    let grid = CorrectionGrid::parse(&img).unwrap();
    assert_eq!(grid.dynamics(), Some(&dynamics()));
    // The first image_len bytes are exactly the version-1 image: what an older parser reads.
    let v1 = image();
    assert_eq!(&img[..v1.len()], &v1[..]);
    let old = CorrectionGrid::parse(&v1).unwrap();
    assert_eq!(old.dynamics(), None);
    assert_eq!(
        old.correction_rad([200.0, 10.0]),
        grid.correction_rad([200.0, 10.0])
    );
    // Erased flash after a plain image: no extension.
    let mut region = v1.clone();
    region.extend([0xFF; 256]);
    assert_eq!(CorrectionGrid::parse(&region).unwrap().dynamics(), None);
    // And after an image with the extension.
    let mut region = img.clone();
    region.extend([0xFF; 256]);
    assert_eq!(
        CorrectionGrid::parse(&region).unwrap().dynamics(),
        Some(&dynamics())
    );
}

#[test]
fn every_bit_flip_in_the_extension_refuses_the_image() {
    let img = image_with_dynamics();
    let start = geometry().image_len();
    // Byte 0..4 is the magic: a flip there makes the block "not an extension" (the image is
    // then read without dynamics); every other flip must be caught.
    for byte in start + 4..img.len() {
        for bit in 0..8 {
            let mut v = img.clone();
            v[byte] ^= 1 << bit;
            assert_eq!(
                CorrectionGrid::parse(&v).unwrap_err(),
                GridError::BadDynamics,
                "byte {byte} bit {bit}"
            );
        }
    }
    for byte in start..start + 4 {
        let mut v = img.clone();
        v[byte] ^= 0x40;
        assert_eq!(CorrectionGrid::parse(&v).unwrap().dynamics(), None);
    }
    // Truncated inside the block.
    assert_eq!(
        CorrectionGrid::parse(&img[..img.len() - 1]).unwrap_err(),
        GridError::BadDynamics
    );
}

#[test]
fn an_extension_left_behind_by_another_image_is_refused() {
    let img = image_with_dynamics();
    let start = geometry().image_len();
    // Another image (one node changed), the old block appended.
    let mut other = image();
    other[HEADER_LEN] ^= 1;
    let n = other.len();
    let crc = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC).checksum(&other[..n - 4]);
    other[n - 4..].copy_from_slice(&crc.to_le_bytes());
    other.extend_from_slice(&img[start..]);
    assert_eq!(
        CorrectionGrid::parse(&other).unwrap_err(),
        GridError::BadDynamics
    );
}

#[test]
fn invalid_dynamics_are_not_encoded_nor_accepted() {
    let g = geometry();
    let nodes = vec![[0.0f32; 2]; g.len()];
    let mut buf = vec![0u8; g.image_len_with_dynamics()];
    let bad = kinematics_core::FiveBarDynamics {
        motor_inertia_kg_m2: [0.0, 1e-3],
        ..dynamics()
    };
    let m = FiveBar::paper_nominal();
    assert_eq!(
        kinematics_core::grid::encode_with_dynamics(&mut buf, &g, &m, &nodes, &bad),
        Err(GridError::BadDynamics)
    );
    let mut short = vec![0u8; g.image_len()];
    assert_eq!(
        kinematics_core::grid::encode_with_dynamics(&mut short, &g, &m, &nodes, &dynamics()),
        Err(GridError::BadEncodeInput)
    );
    // A negative friction written with a valid CRC: refused on parsing.
    let mut img = image_with_dynamics();
    let start = g.image_len();
    img[start + 12 + 4 * 7..start + 16 + 4 * 7].copy_from_slice(&(-0.05f32).to_le_bytes());
    let crc = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC).checksum(&img[start..start + 52]);
    img[start + 52..start + 56].copy_from_slice(&crc.to_le_bytes());
    assert_eq!(
        CorrectionGrid::parse(&img).unwrap_err(),
        GridError::BadDynamics
    );
}

// ---------------------------------------------------------------------------------------------
// The chain with both blocks (grid.rs, "Extension blocks").

use kinematics_core::grid::{append_dynamics, DYNAMICS_LEN, DYNAMICS_MAGIC};

/// The image followed by the blocks in `order` (`b'W'` workspace, `b'D'` dynamics).
fn image_with_chain(order: &[u8]) -> Vec<u8> {
    let mut img = image();
    let n = img.len();
    let mut end = n;
    for b in order {
        let len = if *b == b'W' {
            WORKSPACE_LEN
        } else {
            DYNAMICS_LEN
        };
        img.resize(end + len, 0x55);
        end = match b {
            b'W' => append_workspace(&mut img, n, end, &limits()),
            _ => append_dynamics(&mut img, n, end, &dynamics()),
        }
        .unwrap();
    }
    assert_eq!(end, img.len());
    img
}

#[test]
fn images_with_neither_either_or_both_blocks_in_either_order_are_read() {
    let plain = image();
    let reference = CorrectionGrid::parse(&plain)
        .unwrap()
        .correction_rad([200.0, 10.0])
        .unwrap();
    for order in [&b""[..], b"W", b"D", b"WD", b"DW"] {
        for tail in [&[][..], &[0xFF; 300][..], &b"HRXX unknown bytes"[..]] {
            let mut img = image_with_chain(order);
            img.extend_from_slice(tail);
            let g = CorrectionGrid::parse(&img).unwrap();
            let name = core::str::from_utf8(order).unwrap();
            assert_eq!(
                g.workspace(),
                order.contains(&b'W').then(limits),
                "{name} + {} bytes",
                tail.len()
            );
            assert_eq!(
                g.dynamics(),
                order.contains(&b'D').then(dynamics).as_ref(),
                "{name}"
            );
            assert_eq!(
                g.correction_rad([200.0, 10.0]).unwrap(),
                reference,
                "{name}"
            );
            assert_eq!(
                &img[..plain.len()],
                &plain[..],
                "{name}: a version-1 reader sees the same image"
            );
            let chain: usize = order
                .iter()
                .map(|b| {
                    if *b == b'W' {
                        WORKSPACE_LEN
                    } else {
                        DYNAMICS_LEN
                    }
                })
                .sum();
            assert_eq!(
                g.len_bytes(),
                plain.len() + chain,
                "{name}: the image's bytes end with its chain, not the region"
            );
        }
    }
}

#[test]
fn a_corrupt_second_block_refuses_the_whole_image() {
    let n = geometry().image_len();
    for (order, second_at, err) in [
        (&b"WD"[..], n + WORKSPACE_LEN, GridError::BadDynamics),
        (&b"DW"[..], n + DYNAMICS_LEN, GridError::BadWorkspace),
    ] {
        let img = image_with_chain(order);
        // A flip in the second block's payload or CRC.
        for byte in [second_at + 12, img.len() - 1] {
            let mut v = img.clone();
            v[byte] ^= 0x01;
            assert_eq!(
                CorrectionGrid::parse(&v).unwrap_err(),
                err,
                "{:?} byte {byte}",
                core::str::from_utf8(order)
            );
        }
        // Truncated in the second block.
        assert_eq!(
            CorrectionGrid::parse(&img[..img.len() - 3]).unwrap_err(),
            err
        );
    }
    // Each magic at most once, also with another block between the two.
    let mut twice = image_with_chain(b"DW");
    let d = twice[n..n + DYNAMICS_LEN].to_vec();
    twice.extend_from_slice(&d);
    assert_eq!(
        CorrectionGrid::parse(&twice).unwrap_err(),
        GridError::BadDynamics
    );
}

#[test]
fn the_dynamics_block_has_the_documented_byte_layout() {
    // The table in grid.rs, byte by byte: what the first dynamics-aware parser (HRDY right
    // after the CRC) wrote and read, so images built before the chain still read.
    let img = image_with_dynamics();
    let n = geometry().image_len();
    let b = &img[n..];
    assert_eq!(b.len(), 56);
    assert_eq!(&b[0..4], &DYNAMICS_MAGIC);
    assert_eq!(&b[0..4], b"HRDY");
    assert_eq!(u16::from_le_bytes([b[4], b[5]]), 1);
    assert_eq!(u16::from_le_bytes([b[6], b[7]]), 56);
    assert_eq!(&b[8..12], &img[n - 4..n], "the image's CRC");
    let f = |k: usize| f32::from_le_bytes(b[12 + 4 * k..16 + 4 * k].try_into().unwrap());
    let d = dynamics();
    let want = [
        d.motor_inertia_kg_m2[0],
        d.motor_inertia_kg_m2[1],
        d.tool_mass_kg,
        d.distal_inertia_kg_m2[0],
        d.distal_inertia_kg_m2[1],
        d.viscous_nm_s_per_rad[0],
        d.viscous_nm_s_per_rad[1],
        d.coulomb_nm[0],
        d.coulomb_nm[1],
        d.coulomb_speed_rad_s,
    ];
    for (k, w) in want.iter().enumerate() {
        assert_eq!(f(k), *w, "parameter {k}");
    }
    let crc = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC).checksum(&b[..52]);
    assert_eq!(u32::from_le_bytes(b[52..56].try_into().unwrap()), crc);
}

#[test]
fn append_dynamics_refuses_what_the_parser_would() {
    let mut img = image();
    let n = img.len();
    img.resize(n + DYNAMICS_LEN, 0);
    let bad = kinematics_core::FiveBarDynamics {
        coulomb_speed_rad_s: f32::NAN,
        ..dynamics()
    };
    assert_eq!(
        append_dynamics(&mut img, n, n, &bad),
        Err(GridError::BadDynamics)
    );
    assert_eq!(
        append_dynamics(&mut img[..n + 55], n, n, &dynamics()),
        Err(GridError::BadEncodeInput)
    );
    assert_eq!(
        append_dynamics(&mut img, n, n - 1, &dynamics()),
        Err(GridError::BadEncodeInput)
    );
    img[100] ^= 1;
    assert_eq!(
        append_dynamics(&mut img, n, n, &dynamics()),
        Err(GridError::BadCrc)
    );
}

// ---------------------------------------------------------------------------------------------
// The backlash block (grid, "HRBL").

use kinematics_core::grid::{append_backlash, BACKLASH_LEN, BACKLASH_MAGIC};
use kinematics_core::Backlash;

fn backlash() -> Backlash<f32> {
    Backlash::new([20e-6, 35e-6]).unwrap()
}

/// The image with the workspace and dynamics blocks, then the backlash block (where the
/// writers put it).
fn image_with_backlash() -> Vec<u8> {
    let mut img = image_with_chain(b"WD");
    let (n, end) = (geometry().image_len(), img.len());
    img.resize(end + BACKLASH_LEN, 0x55);
    assert_eq!(
        append_backlash(&mut img, n, end, &backlash()),
        Ok(img.len())
    );
    img
}

#[test]
fn the_backlash_block_round_trips_with_the_documented_layout() {
    let img = image_with_backlash();
    let g = CorrectionGrid::parse(&img).unwrap();
    assert_eq!(g.backlash(), Some(&backlash()));
    assert_eq!(g.workspace(), Some(limits()));
    assert_eq!(g.dynamics(), Some(&dynamics()));
    assert_eq!(g.len_bytes(), img.len());
    // The table in grid.rs, byte by byte.
    let b = &img[img.len() - BACKLASH_LEN..];
    assert_eq!(b[0..4], BACKLASH_MAGIC);
    assert_eq!(u16::from_le_bytes([b[4], b[5]]), 1);
    assert_eq!(u16::from_le_bytes([b[6], b[7]]) as usize, BACKLASH_LEN);
    assert_eq!(BACKLASH_LEN, 24);
    assert_eq!(
        b[8..12],
        img[geometry().image_len() - 4..geometry().image_len()]
    );
    assert_eq!(f32::from_le_bytes([b[12], b[13], b[14], b[15]]), 20e-6);
    assert_eq!(f32::from_le_bytes([b[16], b[17], b[18], b[19]]), 35e-6);
    let crc = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC).checksum(&b[..20]);
    assert_eq!(u32::from_le_bytes([b[20], b[21], b[22], b[23]]), crc);
    // Images without the block read no backlash.
    for order in [&b""[..], b"W", b"D", b"WD", b"DW"] {
        assert_eq!(
            CorrectionGrid::parse(&image_with_chain(order))
                .unwrap()
                .backlash(),
            None
        );
    }
}

#[test]
fn an_older_parser_reads_the_image_before_the_backlash_block_unchanged() {
    // What an older parser reads: the chain up to the first unknown magic. The backlash block
    // goes last, so the bytes before it are the image with its other blocks, bit for bit, and
    // `HRBL` ends that parser's chain like erased flash does.
    let img = image_with_backlash();
    let before = image_with_chain(b"WD");
    assert_eq!(&img[..before.len()], &before[..]);
    let mut older = before.clone();
    older.extend_from_slice(b"HRXX");
    older.extend_from_slice(&img[before.len() + 4..]);
    let g = CorrectionGrid::parse(&older).unwrap();
    assert_eq!((g.backlash(), g.len_bytes()), (None, before.len()));
    // The block may also come first in the chain: the parser reads any order.
    let n = geometry().image_len();
    let mut first = image();
    first.resize(n + BACKLASH_LEN, 0);
    append_backlash(&mut first, n, n, &backlash()).unwrap();
    first.resize(n + BACKLASH_LEN + DYNAMICS_LEN, 0);
    append_dynamics(&mut first, n, n + BACKLASH_LEN, &dynamics()).unwrap();
    let g = CorrectionGrid::parse(&first).unwrap();
    assert_eq!(
        (g.backlash(), g.dynamics()),
        (Some(&backlash()), Some(&dynamics()))
    );
}

#[test]
fn every_bit_flip_in_the_backlash_block_refuses_the_image() {
    let img = image_with_backlash();
    let start = img.len() - BACKLASH_LEN;
    for byte in start + 4..img.len() {
        for bit in 0..8 {
            let mut v = img.clone();
            v[byte] ^= 1 << bit;
            assert_eq!(
                CorrectionGrid::parse(&v).unwrap_err(),
                GridError::BadBacklash,
                "byte {byte} bit {bit}"
            );
        }
    }
    assert_eq!(
        CorrectionGrid::parse(&img[..img.len() - 1]).unwrap_err(),
        GridError::BadBacklash
    );
    // Twice, and left behind by another image.
    let mut twice = img.clone();
    twice.extend_from_slice(&img[start..]);
    assert_eq!(
        CorrectionGrid::parse(&twice).unwrap_err(),
        GridError::BadBacklash
    );
    let mut other = image();
    other[HEADER_LEN] ^= 1;
    let n = other.len();
    let crc = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC).checksum(&other[..n - 4]);
    other[n - 4..].copy_from_slice(&crc.to_le_bytes());
    other.extend_from_slice(&img[start..]);
    assert_eq!(
        CorrectionGrid::parse(&other).unwrap_err(),
        GridError::BadBacklash
    );
}

#[test]
fn a_gap_that_is_not_a_backlash_is_refused_even_with_a_valid_crc() {
    let img = image_with_backlash();
    let start = img.len() - BACKLASH_LEN;
    for bad in [f32::NAN, f32::INFINITY, -1e-6, 0.0101] {
        let mut v = img.clone();
        v[start + 16..start + 20].copy_from_slice(&bad.to_le_bytes());
        let crc = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC).checksum(&v[start..start + 20]);
        v[start + 20..].copy_from_slice(&crc.to_le_bytes());
        assert_eq!(
            CorrectionGrid::parse(&v).unwrap_err(),
            GridError::BadBacklash,
            "{bad}"
        );
    }
    // The bounds themselves are a backlash.
    for ok in [0.0f32, 0.01] {
        let mut v = img.clone();
        v[start + 16..start + 20].copy_from_slice(&ok.to_le_bytes());
        let crc = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC).checksum(&v[start..start + 20]);
        v[start + 20..].copy_from_slice(&crc.to_le_bytes());
        assert_eq!(
            CorrectionGrid::parse(&v)
                .unwrap()
                .backlash()
                .unwrap()
                .beta_rad()[1],
            ok
        );
    }
    // The writer refuses what it cannot place.
    let n = geometry().image_len();
    let mut short = image();
    assert_eq!(
        append_backlash(&mut short, n, n, &backlash()),
        Err(GridError::BadEncodeInput)
    );
}

// ---------------------------------------------------------------------------------------------
// The machine record block (grid, "HRMC").

use kinematics_core::grid::{append_machine, MACHINE_LEN, MACHINE_MAGIC};
use kinematics_core::machine::record::ENCODED_LEN;
use kinematics_core::MachineRecord;

/// The image with every other block, then the machine record (where the writers put it).
fn image_with_machine() -> Vec<u8> {
    let mut img = image_with_backlash();
    let (n, end) = (geometry().image_len(), img.len());
    img.resize(end + MACHINE_LEN, 0x55);
    assert_eq!(
        append_machine(&mut img, n, end, &MachineRecord::paper()),
        Ok(img.len())
    );
    img
}

#[test]
fn the_machine_record_block_round_trips_and_older_parsers_stop_before_it() {
    let img = image_with_machine();
    let g = CorrectionGrid::parse(&img).unwrap();
    assert_eq!(g.machine(), Some(MachineRecord::paper()));
    assert_eq!(g.backlash(), Some(&backlash()));
    assert_eq!(g.len_bytes(), img.len());
    let b = &img[img.len() - MACHINE_LEN..];
    assert_eq!(b[0..4], MACHINE_MAGIC);
    assert_eq!(u16::from_le_bytes([b[4], b[5]]), 1);
    assert_eq!(u16::from_le_bytes([b[6], b[7]]) as usize, MACHINE_LEN);
    assert_eq!((MACHINE_LEN, ENCODED_LEN), (280, 264));
    let mut payload = [0u8; ENCODED_LEN];
    MachineRecord::paper().encode(&mut payload).unwrap();
    assert_eq!(b[12..12 + ENCODED_LEN], payload);
    // A parser that does not know the block reads everything before it, bit for bit.
    let before = image_with_backlash();
    assert_eq!(&img[..before.len()], &before[..]);
    let mut older = img.clone();
    older[before.len()..before.len() + 4].copy_from_slice(b"HRXX");
    let g = CorrectionGrid::parse(&older).unwrap();
    assert_eq!((g.machine(), g.len_bytes()), (None, before.len()));
    assert_eq!(g.backlash(), Some(&backlash()));
}

#[test]
fn a_corrupt_repeated_or_foreign_machine_record_refuses_the_image() {
    let img = image_with_machine();
    let start = img.len() - MACHINE_LEN;
    for byte in (start + 4..img.len()).step_by(7) {
        let mut v = img.clone();
        v[byte] ^= 0x10;
        assert_eq!(
            CorrectionGrid::parse(&v).unwrap_err(),
            GridError::BadMachineRecord,
            "byte {byte}"
        );
    }
    let mut twice = img.clone();
    twice.extend_from_slice(&img[start..]);
    assert_eq!(
        CorrectionGrid::parse(&twice).unwrap_err(),
        GridError::BadMachineRecord
    );
    // A record that fails its own checks, its block CRC made consistent: refused, not ignored.
    let mut v = img.clone();
    let home_x = start + 12 + 196;
    v[home_x..home_x + 4].copy_from_slice(&1000.0f32.to_le_bytes());
    let crc = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC).checksum(&v[start..img.len() - 4]);
    let n = v.len();
    v[n - 4..].copy_from_slice(&crc.to_le_bytes());
    assert_eq!(
        CorrectionGrid::parse(&v).unwrap_err(),
        GridError::BadMachineRecord
    );
    // The writer refuses a record that does not validate, and a buffer without room.
    let mut bad = MachineRecord::paper();
    bad.limits.dynamics_factor = 0.5;
    let (n, end) = (geometry().image_len(), img.len());
    let mut room = img.clone();
    room.resize(end + MACHINE_LEN, 0);
    assert_eq!(
        append_machine(&mut room, n, end, &bad),
        Err(GridError::BadMachineRecord)
    );
    let mut short = image();
    assert_eq!(
        append_machine(&mut short, n, n, &MachineRecord::paper()),
        Err(GridError::BadEncodeInput)
    );
}
