use super::sim::SimFlash;
use super::*;
use kinematics_core::grid::{encode, encode_with_dynamics, GridGeometry};
use kinematics_core::machine::{
    ImageRefusal, MachineMismatch, ModelParameter, ParameterDifference,
};
use kinematics_core::{FiveBar, FiveBarDynamics, GridError};

/// The paper's machine (the built-in one) with the default servo's slope-change limit.
fn image_check() -> ImageCheck {
    crate::settings::Settings::default().image_check()
}

fn image(value: f32) -> Vec<u8> {
    let g = GridGeometry {
        nx: 3,
        ny: 3,
        x0_mm: 160.0,
        y0_mm: -80.0,
        step_x_mm: 50.0,
        step_y_mm: 80.0,
    };
    let mut img = vec![0u8; g.image_len()];
    encode(
        &mut img,
        &g,
        &FiveBar::paper_nominal(),
        &[[value, -value]; 9],
    )
    .unwrap();
    img
}

fn crc(b: &[u8]) -> u32 {
    image_crc(b)
}

/// Regression: zlib's CRC-32 over whole grid images is one constant (each image ends with
/// its own CRC-32), so it cannot tell images apart; the id's CRC-32C does.
#[test]
fn different_images_have_different_ids() {
    let (a, b) = (image(1e-4), image(2e-4));
    assert_eq!(
        CRC32.checksum(&a),
        CRC32.checksum(&b),
        "the residue the id must not use"
    );
    assert_ne!(crc(&a), crc(&b));
}

type Small<'a> = SimFlash<'a, 8, 256>;

fn open(bytes: &mut [u8]) -> SlotStore<Small<'_>> {
    SlotStore::open(SimFlash::new(bytes), image_check())
}

fn upload<F: SlotFlash>(
    store: &mut SlotStore<F>,
    img: &[u8],
    chunk: usize,
) -> Result<CalibrationId, SlotError> {
    store.begin(img.len(), store.active_id())?;
    for (k, c) in img.chunks(chunk).enumerate() {
        store.write(k * chunk, c)?;
    }
    store.commit()
}

/// The record's image CRC is not redundant with the grid's own CRC: a record stays behind
/// when a probe reflashes the slot's start with another image of the same length (a
/// `probe-rs download` writes only the pages it covers; the record is in the slot's last
/// page). The other image parses and has the record's length; only the record's CRC-32C
/// tells it is not the image the record committed. It must not count: the id reported
/// (what the host compares with its file) is always that of the bytes in force.
#[test]
fn a_record_left_behind_by_another_image_does_not_count() {
    let (committed, reflashed) = (image(1e-4), image(3e-4));
    assert_eq!(committed.len(), reflashed.len());
    let mut region = vec![0xFFu8; 4096];
    let id = upload(&mut open(&mut region), &committed, 64).unwrap();
    assert_eq!((id.slot, id.sequence), (0, 1));
    // The probe writes the other image over slot A's start; the record stays.
    region[..reflashed.len()].copy_from_slice(&reflashed);
    let store = open(&mut region);
    let (bytes, id) = store.active().unwrap();
    assert_eq!(bytes, &reflashed[..]);
    assert_eq!(
        id.crc32,
        crc(&reflashed),
        "the id reported is the bytes' in force, not the stale record's"
    );
    assert_eq!(id.sequence, 0, "the reflashed image, without a record");
}

#[test]
fn a_probe_flashed_image_is_in_force_and_an_upload_switches_to_the_other_slot() {
    let (old, new) = (image(1e-4), image(2e-4));
    let mut region = vec![0xFFu8; 4096];
    region[..old.len()].copy_from_slice(&old);
    let mut store = open(&mut region);
    assert_eq!(store.slot_len(), 2048);
    let (bytes, id) = store.active().unwrap();
    assert_eq!(
        (bytes, id),
        (
            &old[..],
            CalibrationId {
                slot: 0,
                sequence: 0,
                crc32: crc(&old),
                len: old.len() as u32
            }
        )
    );
    // Odd chunk sizes: the store buffers partial write units.
    let id = upload(&mut store, &new, 7).unwrap();
    assert_eq!(
        id,
        CalibrationId {
            slot: 1,
            sequence: 1,
            crc32: crc(&new),
            len: new.len() as u32
        }
    );
    assert_eq!(store.active().unwrap().0, &new[..]);
    // The next one goes back to slot A, over the probe-flashed image, and wins on sequence.
    let third = image(3e-4);
    assert_eq!(upload(&mut store, &third, 64).unwrap().slot, 0);
    let store = open(&mut region);
    assert_eq!(
        store.active().unwrap(),
        (
            &third[..],
            CalibrationId {
                slot: 0,
                sequence: 2,
                crc32: crc(&third),
                len: third.len() as u32
            }
        )
    );
}

#[test]
fn bad_uploads_are_refused_and_the_old_image_kept() {
    let old = image(1e-4);
    let mut region = vec![0xFFu8; 4096];
    region[..old.len()].copy_from_slice(&old);
    let mut store = open(&mut region);
    let before = store.active_id();
    // Corrupt: one node flipped, the CRC no longer matches.
    let mut bad = image(2e-4);
    bad[100] ^= 0x10;
    assert_eq!(
        upload(&mut store, &bad, 32),
        Err(SlotError::Image(ImageError::Grid(GridError::BadCrc)))
    );
    // Another machine: 160 mm links (a valid image, CRC and all).
    let g = GridGeometry {
        nx: 3,
        ny: 3,
        x0_mm: 160.0,
        y0_mm: -80.0,
        step_x_mm: 50.0,
        step_y_mm: 80.0,
    };
    let mut other = vec![0u8; g.image_len()];
    let model = FiveBar {
        a_mm: 160.0,
        ..FiveBar::paper_nominal()
    };
    encode(&mut other, &g, &model, &[[0.0; 2]; 9]).unwrap();
    // Refused by the physical judgement, naming the link that explains it with both values.
    let refusal = upload(&mut store, &other, 32);
    assert!(
        matches!(
            refusal,
            Err(SlotError::Image(ImageError::Refused(
                ImageRefusal::OtherMachine(MachineMismatch::Geometry {
                    parameter: Some(ParameterDifference {
                        parameter: ModelParameter::A,
                        image: 160.0,
                        controller: 150.0
                    }),
                    ..
                })
            )))
        ),
        "{refusal:?}"
    );
    assert_eq!(store.active_id(), before);
    // Lengths, order, protocol.
    assert_eq!(
        store.begin(10, store.active_id()),
        Err(SlotError::BadLength { max: 2016 })
    );
    assert_eq!(
        store.begin(5000, store.active_id()),
        Err(SlotError::BadLength { max: 2016 })
    );
    assert_eq!(store.write(0, &[1]), Err(SlotError::NoUpload));
    assert_eq!(store.commit(), Err(SlotError::NoUpload));
    let good = image(2e-4);
    store.begin(good.len(), store.active_id()).unwrap();
    store.write(0, &good[..10]).unwrap();
    assert_eq!(
        store.write(0, &good[..10]),
        Err(SlotError::OutOfOrder { expected: 10 })
    );
    assert_eq!(store.commit(), Err(SlotError::Incomplete { received: 10 }));
    store.begin(good.len(), store.active_id()).unwrap();
    assert_eq!(store.write(0, &[0u8; 200]), Err(SlotError::TooMuchData));
    // Announced longer than the image: trailing bytes are refused, not ignored.
    let mut padded = good.clone();
    padded.extend([0u8; 8]);
    assert!(matches!(
        upload(&mut store, &padded, 64),
        Err(SlotError::BadLength { .. })
    ));
    assert_eq!(store.active_id(), before);
    assert_eq!(open(&mut region).active_id(), before, "and after a reboot");
}

#[test]
fn an_empty_region_has_no_image_and_takes_one() {
    let mut region = vec![0xFFu8; 4096];
    let mut store = open(&mut region);
    assert!(store.active().is_none());
    let img = image(1e-4);
    let id = upload(&mut store, &img, 13).unwrap();
    assert_eq!((id.slot, id.sequence), (0, 1));
    // QEMU's RAM-backed region starts zeroed, not erased: no record there either.
    let mut zeros = vec![0u8; 4096];
    assert!(open(&mut zeros).active().is_none());
}

/// The guarantee: the power fails after every single byte operation (erase or program) of
/// an upload, then the machine reboots. The image in force is the old one until the commit
/// record's last write unit is complete, and the new one from then on; never none, never a
/// mix. Three uploads in a row, so both slots are overwritten, with and without dynamics.
#[test]
fn a_power_cut_at_every_byte_of_an_upload_leaves_the_old_image_or_the_new_one() {
    let g = GridGeometry {
        nx: 3,
        ny: 3,
        x0_mm: 160.0,
        y0_mm: -80.0,
        step_x_mm: 50.0,
        step_y_mm: 80.0,
    };
    let mut with_dynamics = vec![0u8; g.image_len_with_dynamics()];
    let dynamics = FiveBarDynamics {
        motor_inertia_kg_m2: [5e-3, 5e-3],
        tool_mass_kg: 0.2,
        distal_inertia_kg_m2: [-2e-4, -2e-4],
        viscous_nm_s_per_rad: [0.01; 2],
        coulomb_nm: [0.02; 2],
        coulomb_speed_rad_s: 0.01,
    };
    encode_with_dynamics(
        &mut with_dynamics,
        &g,
        &FiveBar::paper_nominal(),
        &[[5e-5, 1e-5]; 9],
        &dynamics,
    )
    .unwrap();
    let images = [image(1e-4), image(2e-4), with_dynamics, image(3e-4)];
    let mut region = vec![0xFFu8; 4096];
    region[..images[0].len()].copy_from_slice(&images[0]);
    let mut cuts = 0;
    for step in 1..images.len() {
        let (old, new) = (&images[step - 1], &images[step]);
        let snapshot = region.clone();
        // The uninterrupted upload: how many byte operations it takes.
        let total = {
            let mut r = snapshot.clone();
            let mut store = open(&mut r);
            upload(&mut store, new, 24).unwrap();
            store.flash().ops
        };
        assert!(total > 2048, "erase and program counted: {total}");
        for budget in 0..=total {
            let mut r = snapshot.clone();
            let mut store = open(&mut r);
            store.flash.budget = Some(budget);
            let done = upload(&mut store, new, 24).is_ok();
            let after = open(&mut r);
            let (bytes, id) = after.active().expect("an image in force after every cut");
            if done {
                assert_eq!(
                    bytes,
                    &new[..],
                    "cut after {budget} of {total}: committed, the new image"
                );
            } else {
                assert_eq!(
                    bytes,
                    &old[..],
                    "cut after {budget} of {total}: the old image"
                );
                assert!(budget < total);
            }
            assert_eq!(id.crc32, crc(bytes));
            cuts += 1;
        }
        region = snapshot;
        let mut store = open(&mut region);
        upload(&mut store, new, 24).unwrap();
    }
    println!("{cuts} power cuts, each followed by a reboot");
}

/// The same at write-unit granularity on the boards' real geometry (64 KiB region, 2 KiB
/// pages, 8-byte double words, the QEMU firmware's bundled-size image): a cut after every
/// programmed unit and after every erased page.
#[test]
fn a_power_cut_after_every_write_unit_on_the_real_geometry() {
    let g = GridGeometry {
        nx: 21,
        ny: 31,
        x0_mm: 162.132,
        y0_mm: -75.0,
        step_x_mm: 5.0,
        step_y_mm: 5.0,
    };
    let make = |v: f32| {
        let mut img = vec![0u8; g.image_len()];
        encode(
            &mut img,
            &g,
            &FiveBar::paper_nominal(),
            &vec![[v, -v]; g.len()],
        )
        .unwrap();
        img
    };
    let (old, new) = (make(1e-4), make(2e-4));
    let mut region = vec![0xFFu8; 65536];
    region[..old.len()].copy_from_slice(&old);
    let snapshot = region.clone();
    fn open64(r: &mut [u8]) -> SlotStore<SimFlash<'_, 8, 2048>> {
        SlotStore::open(SimFlash::new(r), image_check())
    }
    let (ops, units) = {
        let mut r = snapshot.clone();
        let mut s = open64(&mut r);
        upload(&mut s, &new, 256).unwrap();
        (s.flash().ops, s.flash().units)
    };
    let erase_ops = 32768;
    assert_eq!(ops, erase_ops + units * 8);
    // Cut points: every erased page, and every byte boundary of every unit programmed.
    let cuts = (0..=16)
        .map(|p| p * 2048)
        .chain((0..=units).map(|u| erase_ops + u * 8));
    for budget in cuts {
        let mut r = snapshot.clone();
        let mut s = open64(&mut r);
        s.flash.budget = Some(budget);
        let done = upload(&mut s, &new, 256).is_ok();
        let after = open64(&mut r);
        let expected = if done { &new } else { &old };
        assert_eq!(
            after.active().unwrap().0,
            &expected[..],
            "cut after {budget} of {ops}"
        );
        assert_eq!(done, budget == ops);
    }
}

#[test]
fn a_torn_record_never_counts() {
    // Every prefix of a record, programmed over erased flash, and a record with a flipped
    // bit in any byte: none decodes.
    let r = encode_record(7, 148, 0xDEAD_BEEF);
    assert_eq!(decode_record(&r), Some((7, 148, 0xDEAD_BEEF)));
    for n in 0..RECORD_LEN {
        let mut torn = [0xFFu8; RECORD_LEN];
        torn[..n].copy_from_slice(&r[..n]);
        assert_eq!(decode_record(&torn), None, "prefix {n}");
        for bit in 0..8 {
            let mut flipped = r;
            flipped[n] ^= 1 << bit;
            assert_eq!(decode_record(&flipped), None, "byte {n} bit {bit}");
        }
    }
}
