//! End to end on the host, no QEMU needed: the firmware's configuration map, and a closed-loop
//! recording that goes through the recording CSV and comes back bit for bit through the host
//! build of the firmware's loop (what `visco replay` compares the firmware with).
//!
//! The firmware half (the same recordings through the image under QEMU, the lockstep run and
//! the instruction counts) is `cargo xtask firmware-test`.

use visco::replay::{
    core_config, inputs, read_recording, reference, simulate, FirmwareConfig, InputKind,
};
use visco::sample::Sample;
use visco::telemetry::{first_difference, first_record_difference};
use visco_protocol::Mode;

/// Every settable field is mapped to the field of that name: staged as NaN, the
/// configuration is refused naming it (arrays by their name, e.g. `dive.estimator.p0`).
#[test]
fn every_parameter_names_its_field() {
    let mut unchecked = Vec::new();
    for name in core_config::PARAMS {
        let mut fw = FirmwareConfig::default();
        fw.set(name, f64::NAN).unwrap();
        match fw.core_config() {
            Err(e) => {
                let array = name
                    .rsplit_once('.')
                    .map(|(a, i)| (a, i.parse::<u8>().is_ok()));
                let expected = match array {
                    Some((a, true)) => a,
                    _ => name,
                };
                // The core checks the tap's time budget (which includes the ramps) before the
                // excitation itself.
                let expected = if name == "dive.excitation.ramp_s" {
                    "dive.tap_s"
                } else {
                    expected
                };
                assert_eq!(e.field, expected, "staging {name} = NaN: {e}");
            }
            Ok(_) => unchecked.push(name),
        }
    }
    // Entries the default regressors do not use (3-parameter SVE, 2-parameter DIVE).
    assert!(
        unchecked.iter().all(|n| n.ends_with(".2")),
        "accepted NaN for {unchecked:?}"
    );
}

#[test]
fn staged_fields_replace_only_themselves() {
    let base = FirmwareConfig::default().core_config().unwrap();
    assert_eq!(
        base,
        visco_core::Config::paper(core_config::DEFAULT_SAMPLE_RATE_HZ)
    );
    let mut fw = FirmwareConfig::default();
    fw.set("dive.tap_s", 0.05).unwrap();
    fw.set("sve.pixels", 20.0).unwrap();
    let c = fw.core_config().unwrap();
    let mut expected = base;
    expected.dive.tap_s = 0.05;
    expected.sve.pixels = 20;
    assert_eq!(c, expected);
    // Whole numbers and enum codes are checked by name.
    fw.set("sve.pixels", 20.5).unwrap();
    assert_eq!(fw.core_config().unwrap_err().field, "sve.pixels");
    let mut fw = FirmwareConfig::default();
    fw.set("dive.regressor", 2.0).unwrap();
    assert_eq!(fw.core_config().unwrap_err().field, "dive.regressor");
    assert!(fw.set("dive.no_such_field", 1.0).is_err());
}

/// One short DIVE tap at 1 MHz: closed loop on the host, written as a recording CSV, read
/// back, and replayed through the host build of the loop: every output and the tap record
/// come back bit for bit, from ADC codes recovered exactly from the CSV's metres.
#[test]
fn closed_loop_recording_replays_bit_for_bit_from_its_csv() {
    let mut fw = FirmwareConfig::default();
    for (k, v) in [
        ("dive.nx", 1.0),
        ("dive.ny", 1.0),
        ("dive.x0_m", 2.5e-6),
        ("dive.y0_m", 2.5e-6),
        ("dive.tap_s", 0.025),
    ] {
        fw.set(k, v).unwrap();
    }
    let sim = simulate(&fw, Mode::Dive, &Sample::cell_phantom(), 7, 100_000).unwrap();
    // One tap, to its end (the dwell is stretched to its minimum when the tap is this short).
    assert_eq!(sim.records.len(), 1);
    let last = sim.steps.last().unwrap();
    assert_eq!(
        last.status >> visco_core::status::PHASE_SHIFT,
        visco_core::Phase::Done as u32
    );
    assert!(sim.steps.len() < 60_000, "{} samples", sim.steps.len());
    let tap = sim.records[0];
    assert!(
        tap.samples > 5_000 && tap.k_n_per_m > 0.05 && tap.c_ns_per_m > 0.0,
        "{tap:?}"
    );
    let path = std::env::temp_dir().join(format!("visco-replay-test-{}.csv", std::process::id()));
    sim.recording.write(&path).unwrap();
    let (rec, fw_back) = read_recording(&path).unwrap();
    std::fs::remove_file(&path).unwrap();
    assert_eq!(fw_back.to_metadata(), fw.to_metadata());
    let cfg = fw_back.core_config().unwrap();
    assert_eq!(cfg, sim.config);
    let adc = fw_back.adc(&cfg).unwrap();
    assert_eq!(adc, sim.adc);
    let inp = inputs(&rec.d_m, &adc, InputKind::Auto);
    assert_eq!(inp.kind, InputKind::Codes);
    assert_eq!(inp.codes, sim.codes);
    let (steps, records) = reference(&cfg, Mode::Dive, &inp.d).unwrap();
    assert_eq!(first_difference(&steps, &sim.steps), None);
    assert_eq!(first_record_difference(&records, &sim.records), None);
    // The recording's U is the U the loop applied: row k + 1 holds step k's output.
    for (s, u) in steps.iter().zip(rec.u_m.iter().skip(1)) {
        assert_eq!(s.u_m as f64, *u);
    }
}
