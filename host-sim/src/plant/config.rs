//! Plant configuration (SI units throughout).

use super::PlantError;

/// Boltzmann constant (J/K).
pub const BOLTZMANN_J_PER_K: f64 = 1.380_649e-23;

/// The cantilever's first mode (2): the core's type, one definition for the estimator and the
/// plant.
pub use visco_core::Cantilever;

/// A uniform converter (ADC or DAC) over `[min, max)`: `2^bits` codes, code `q` stands for
/// `min + q·lsb` with `lsb = (max − min)/2^bits`. A symmetric range (±r) therefore has 0 as a
/// code. Values beyond the range saturate at the first or last code.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Converter {
    pub min_m: f64,
    pub max_m: f64,
    pub bits: u32,
    /// `false`: the signal passes unquantised and unclamped (an ideal converter).
    pub enabled: bool,
}

impl Converter {
    /// A bipolar 16-bit converter over `±range_m`.
    pub fn bipolar16(range_m: f64) -> Self {
        Converter {
            min_m: -range_m,
            max_m: range_m,
            bits: 16,
            enabled: true,
        }
    }
    /// The size of one code.
    pub fn lsb_m(&self) -> f64 {
        (self.max_m - self.min_m) / (1u64 << self.bits) as f64
    }
    fn validate(&self, name: &'static str) -> Result<(), PlantError> {
        if !(self.min_m.is_finite() && self.max_m.is_finite() && self.max_m > self.min_m) {
            return Err(PlantError::config(
                name,
                format!(
                    "range [{}, {}] m must be finite and non-empty",
                    self.min_m, self.max_m
                ),
            ));
        }
        if !(1..=32).contains(&self.bits) {
            return Err(PlantError::config(
                name,
                format!("{} bits: must be 1 to 32", self.bits),
            ));
        }
        Ok(())
    }
}

/// Travel limits of a piezo axis: the position is clamped to `[min, max]` after the DAC.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Travel {
    pub min_m: f64,
    pub max_m: f64,
}

impl Travel {
    fn validate(&self, name: &'static str) -> Result<(), PlantError> {
        if !(self.min_m.is_finite() && self.max_m.is_finite() && self.max_m >= self.min_m) {
            return Err(PlantError::config(
                name,
                format!(
                    "travel [{}, {}] m must be finite with min ≤ max",
                    self.min_m, self.max_m
                ),
            ));
        }
        Ok(())
    }
}

/// Everything the plant needs besides the sample and the seed.
#[derive(Clone, Debug, PartialEq)]
pub struct PlantConfig {
    pub cantilever: Cantilever,
    /// Radius R of the spherical tip.
    pub tip_radius_m: f64,
    /// Temperature of the thermal force on the cantilever.
    pub temperature_k: f64,
    /// Thermal force noise on/off.
    pub thermal_noise: bool,
    /// Deflection ADC (the controller's input D).
    pub adc_deflection: Converter,
    /// Vertical DAC (the controller's output U).
    pub dac_z: Converter,
    /// Lateral DACs (X and Y share the configuration).
    pub dac_xy: Converter,
    /// Vertical piezo travel (U after the DAC).
    pub travel_z: Travel,
    /// Lateral piezo travel.
    pub travel_xy: Travel,
    /// Plant step = DAC period (s). [`super::Plant::set_time_step`] changes it.
    pub time_step_s: f64,
    /// The tip's lateral position is taken as fixed until it has moved this far (m) since the
    /// element thresholds were last computed. See the plant docs for the error bound; with the
    /// default lateral DAC (0.15 nm LSB) every lateral change refreshes, which is exact.
    pub lateral_refresh_m: f64,
}

impl PlantConfig {
    /// The paper's simulation (section 5.1): f0 = 20 kHz, K = 0.18 N/m, C = 1.48×10⁻⁸ N·s/m,
    /// M = 1.18×10⁻¹¹ kg (Q = 100), R = 300 nm, 300 K; with the measurement realism of a real
    /// instrument on: thermal noise, 16-bit ADC over ±2.5 µm (the paper's DIVE swings D by ±1.2 µm
    /// around −0.2 µm; the core's `Config::paper` has the same range), 16-bit Z DAC over ±3 µm (the piezo
    /// travel), 16-bit lateral DACs over −2.5…7.5 µm (a 10 µm scanner centred on the 5 µm
    /// sample, 0.15 nm LSB); 1 µs step (1 MHz loop).
    ///
    /// K, C and M are the paper's numbers as given; they make `f0 = √(K/M)/2π = 19.66 kHz` and
    /// `Q = √(K·M)/C = 98.5`, which the paper rounds to 20 kHz and 100.
    pub fn paper() -> Self {
        PlantConfig {
            cantilever: Cantilever::PAPER,
            tip_radius_m: 300e-9,
            temperature_k: 300.0,
            thermal_noise: true,
            adc_deflection: Converter::bipolar16(2.5e-6),
            dac_z: Converter::bipolar16(3e-6),
            dac_xy: Converter {
                min_m: -2.5e-6,
                max_m: 7.5e-6,
                bits: 16,
                enabled: true,
            },
            travel_z: Travel {
                min_m: -3e-6,
                max_m: 3e-6,
            },
            travel_xy: Travel {
                min_m: -2.5e-6,
                max_m: 7.5e-6,
            },
            time_step_s: 1e-6,
            lateral_refresh_m: 0.1e-9,
        }
    }

    /// [`PlantConfig::paper`] with every measurement effect off: no noise, ideal converters.
    /// For analytic tests and for separating integration error from measurement error.
    pub fn ideal() -> Self {
        PlantConfig::paper().without_noise().without_quantisation()
    }

    /// Thermal noise off.
    pub fn without_noise(mut self) -> Self {
        self.thermal_noise = false;
        self
    }

    /// All converters ideal (no quantisation, no converter saturation; the piezo travel clamp
    /// stays).
    pub fn without_quantisation(mut self) -> Self {
        self.adc_deflection.enabled = false;
        self.dac_z.enabled = false;
        self.dac_xy.enabled = false;
        self
    }

    pub(crate) fn validate(&self) -> Result<(), PlantError> {
        let c = &self.cantilever;
        let pos = |name: &'static str, v: f64| {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(PlantError::config(
                    name,
                    format!("{v} must be finite and positive"),
                ))
            }
        };
        pos("cantilever.k_n_per_m", c.k_n_per_m)?;
        pos("cantilever.m_kg", c.m_kg)?;
        if !(c.c_ns_per_m.is_finite() && c.c_ns_per_m >= 0.0) {
            return Err(PlantError::config(
                "cantilever.c_ns_per_m",
                format!("{} must be finite and ≥ 0", c.c_ns_per_m),
            ));
        }
        pos("tip_radius_m", self.tip_radius_m)?;
        if !(self.temperature_k.is_finite() && self.temperature_k >= 0.0) {
            return Err(PlantError::config(
                "temperature_k",
                format!("{} must be finite and ≥ 0", self.temperature_k),
            ));
        }
        pos("time_step_s", self.time_step_s)?;
        if !(self.lateral_refresh_m.is_finite() && self.lateral_refresh_m >= 0.0) {
            return Err(PlantError::config(
                "lateral_refresh_m",
                format!("{} must be finite and ≥ 0", self.lateral_refresh_m),
            ));
        }
        self.adc_deflection.validate("adc_deflection")?;
        self.dac_z.validate("dac_z")?;
        self.dac_xy.validate("dac_xy")?;
        self.travel_z.validate("travel_z")?;
        self.travel_xy.validate("travel_xy")?;
        Ok(())
    }
}
