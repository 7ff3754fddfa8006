//! Measurement realism: thermal noise, ADC/DAC quantisation and saturation, piezo travel,
//! determinism, bad input, and the effect hooks.

use visco::plant::{
    Converter, Effect, EffectContext, Plant, PlantConfig, Travel, BOLTZMANN_J_PER_K,
};
use visco::sample::Sample;

const OFF: f64 = -2.0e-6; // lateral parking spot off the sample: free cantilever

fn plant(cfg: PlantConfig, seed: u64) -> Plant {
    let mut p = Plant::new(cfg, Sample::cell_phantom(), seed).unwrap();
    p.settle(0.0, OFF, OFF);
    p
}

/// Equipartition: the free deflection variance is k_B·T/K (√ ≈ 0.152 nm at 300 K, 0.18 N/m).
/// The deflection's correlation time is the envelope's 2M/C = 1.6 ms, so a 10 s run has about
/// T/(2·1.6 ms) ≈ 3000 independent samples of the envelope: the variance estimate's relative
/// standard deviation is ≈ √(1/3000)·… ≈ 1.5 %; 5 % is ≥ 3σ. The ADC adds LSB²/12 (0.4 % of
/// the variance), inside the same tolerance.
#[test]
fn thermal_deflection_variance_is_kt_over_k() {
    let cfg = PlantConfig::paper();
    let expected = BOLTZMANN_J_PER_K * cfg.temperature_k / cfg.cantilever.k_n_per_m;
    for (h, seconds) in [(1e-6, 10.0), (2e-6, 10.0)] {
        let mut p = plant(PlantConfig::paper(), 11);
        p.set_time_step(h).unwrap();
        for _ in 0..(10e-3 / h) as usize {
            p.step(0.0, OFF, OFF); // 10 ms to reach the stationary state
        }
        let n = (seconds / h) as usize;
        let (mut s1, mut s2, mut m1, mut m2) = (0.0, 0.0, 0.0, 0.0);
        for _ in 0..n {
            let meas = p.step(0.0, OFF, OFF);
            let d = p.true_deflection_m();
            s1 += d;
            s2 += d * d;
            m1 += meas;
            m2 += meas * meas;
        }
        let nf = n as f64;
        let var = s2 / nf - (s1 / nf).powi(2);
        let var_adc = m2 / nf - (m1 / nf).powi(2);
        println!(
            "h = {h:e} s: σ_D = {:.4} nm true, {:.4} nm ADC, √(kT/K) = {:.4} nm; var ratio {:.4} / {:.4}",
            var.sqrt() * 1e9,
            var_adc.sqrt() * 1e9,
            expected.sqrt() * 1e9,
            var / expected,
            var_adc / expected
        );
        assert!((var / expected - 1.0).abs() < 0.05);
        assert!((var_adc / expected - 1.0).abs() < 0.05);
    }
}

#[test]
fn noise_is_seeded() {
    let run = |seed| {
        let mut p = plant(PlantConfig::paper(), seed);
        (0..1000)
            .map(|_| p.step(0.0, OFF, OFF))
            .collect::<Vec<f64>>()
    };
    assert_eq!(run(5), run(5));
    assert_ne!(run(5), run(6));
    // Noise off: exactly at rest.
    let mut p = plant(PlantConfig::paper().without_noise(), 5);
    for _ in 0..1000 {
        assert_eq!(p.step(0.0, OFF, OFF), 0.0);
    }
}

#[test]
fn adc_quantises_and_saturates() {
    let mut cfg = PlantConfig::ideal();
    cfg.adc_deflection = Converter::bipolar16(1e-6);
    let lsb = cfg.adc_deflection.lsb_m();
    assert!((lsb - 2e-6 / 65536.0).abs() < 1e-25);
    let mut p = plant(cfg.clone(), 1);
    // A ring-down sweeps D through many codes.
    p.set_tip_state_nm(300.0, 0.0);
    for _ in 0..5000 {
        let m = p.step(0.0, OFF, OFF);
        let d = p.true_deflection_m();
        assert!((m - d).abs() <= 0.5 * lsb * (1.0 + 1e-9), "{m} vs {d}");
        let code = (m + 1e-6) / lsb;
        assert!((code - code.round()).abs() < 1e-6, "not on a code: {code}");
    }
    // Saturation: a ±10 nm ADC, indentation deflects by ≈ −30 nm, a pull-off ring by +.
    cfg.adc_deflection = Converter::bipolar16(10e-9);
    let lsb = cfg.adc_deflection.lsb_m();
    let mut p = Plant::new(cfg, Sample::cell_phantom(), 1).unwrap();
    p.settle(0.0, 2.5e-6, 2.5e-6);
    let surface = p.first_contact_z_m().unwrap();
    let m = p.step(surface - 200e-9, 2.5e-6, 2.5e-6);
    for _ in 0..20_000 {
        p.step(surface - 200e-9, 2.5e-6, 2.5e-6);
    }
    let m_end = p.measured_deflection_m();
    assert!(p.true_deflection_m() < -10e-9);
    assert_eq!(m_end, -10e-9, "negative full scale is code 0 = −range");
    let _ = m;
    // Positive side: free cantilever pulled 50 nm below its rest: D = U − Z = +50 nm.
    p.settle(0.0, OFF, OFF);
    p.set_tip_state_nm(-50.0, 0.0);
    let m = p.step(0.0, OFF, OFF);
    assert!(p.true_deflection_m() > 10e-9);
    assert!(
        (m - (10e-9 - lsb)).abs() < 1e-20,
        "top code = range − LSB, got {m}"
    );
}

#[test]
fn dacs_quantise_and_piezo_travel_clamps() {
    let mut cfg = PlantConfig::paper().without_noise();
    cfg.travel_z = Travel {
        min_m: -1e-6,
        max_m: 1e-6,
    };
    let lsb_z = cfg.dac_z.lsb_m();
    let lsb_xy = cfg.dac_xy.lsb_m();
    println!(
        "LSB: z {:.4} nm, xy {:.4} nm, ADC {:.4} nm",
        lsb_z * 1e9,
        lsb_xy * 1e9,
        cfg.adc_deflection.lsb_m() * 1e9
    );
    let mut p = plant(cfg, 1);
    for u in [1.234567e-9, -0.77e-9, 123.4567e-9, 999.9e-9] {
        p.step(u, OFF, OFF);
        let held = p.piezo_z_m();
        assert!((held - u).abs() <= 0.5 * lsb_z * (1.0 + 1e-9));
        let code = (held + 3e-6) / lsb_z;
        assert!(
            (code - code.round()).abs() < 1e-6,
            "u {u:e}: held {held:e}, code {code}"
        );
    }
    // Beyond the travel (but inside the DAC): clamped to ±1 µm; beyond the DAC: its range.
    p.step(2e-6, OFF, OFF);
    assert_eq!(p.piezo_z_m(), 1e-6);
    p.step(-5e-6, OFF, OFF);
    assert_eq!(p.piezo_z_m(), -1e-6);
    // Lateral: quantised; beyond the range the DAC saturates at its top code, 7.5 µm − LSB.
    p.step(0.0, 1.23456789e-6, 9e-6);
    let [x, y, _] = p.tip_position_m();
    assert!((x - 1.23456789e-6).abs() <= 0.5 * lsb_xy * (1.0 + 1e-9));
    assert!((y - (7.5e-6 - lsb_xy)).abs() < 1e-18, "{y}");
}

#[test]
fn non_finite_commands_are_ignored() {
    let mut p = plant(PlantConfig::paper(), 1);
    p.step(10e-9, OFF, OFF);
    let u = p.piezo_z_m();
    for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
        let d = p.step(bad, OFF, bad);
        assert!(d.is_finite());
        assert_eq!(p.piezo_z_m(), u);
    }
    assert_eq!(p.stats().rejected_commands, 3);
    assert!(p.tip_z_m().is_finite());
}

#[test]
fn invalid_configuration_is_an_error_with_context() {
    let mut cfg = PlantConfig::paper();
    cfg.cantilever.m_kg = -1.0;
    let e = Plant::new(cfg, Sample::cell_phantom(), 1).unwrap_err();
    assert!(e.to_string().contains("cantilever.m_kg"), "{e}");
    let mut cfg = PlantConfig::paper();
    cfg.adc_deflection.bits = 0;
    let e = Plant::new(cfg, Sample::cell_phantom(), 1).unwrap_err();
    assert!(e.to_string().contains("adc_deflection"), "{e}");
    let mut p = plant(PlantConfig::paper(), 1);
    assert!(p.set_time_step(0.0).is_err());
    assert!(p.set_time_step(f64::NAN).is_err());
}

/// A test effect: a constant force, a detector offset and a drag, through each hook.
struct Probe {
    force_nn: f64,
    offset_nm: f64,
    drag: f64,
    steps: usize,
}

impl Effect for Probe {
    fn name(&self) -> &str {
        "probe"
    }
    fn tip_force_nn(&self, _ctx: &EffectContext) -> f64 {
        self.force_nn
    }
    fn linear_terms(&self) -> (f64, f64) {
        (0.0, self.drag)
    }
    fn measured_deflection_nm(&self, _ctx: &EffectContext, d_nm: f64) -> f64 {
        d_nm + self.offset_nm
    }
    fn end_of_step(&mut self, _ctx: &EffectContext) {
        self.steps += 1;
    }
}

#[test]
fn effect_hooks_act() {
    let mut p = plant(PlantConfig::ideal(), 1);
    p.add_effect(Box::new(Probe {
        force_nn: 1.8,
        offset_nm: 3.0,
        drag: 1.0,
        steps: 0,
    }));
    // With 1.8 nN up and K = 0.18 N/m the tip rests 10 nm higher: D = −10 nm, read as −7 nm.
    // The extra drag (1e-6 N·s/m, 70× C) settles it within 20 ms.
    let mut m = 0.0;
    for _ in 0..20_000 {
        m = p.step(0.0, OFF, OFF);
    }
    assert!((p.tip_z_m() - 10e-9).abs() < 1e-12, "{}", p.tip_z_m());
    assert!((m + 7e-9).abs() < 1e-12, "{m}");
    p.clear_effects();
    for _ in 0..50_000 {
        m = p.step(0.0, OFF, OFF);
    }
    assert!(m.abs() < 1e-12);
}
