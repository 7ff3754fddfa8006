"""Type stubs of visco (units: SI, in every name's suffix; see the module docstring)."""

import os
from typing import Any, Callable, Dict, Iterable, List, Mapping, Optional, Sequence, Tuple, Union

import numpy as np
import numpy.typing as npt

PathLike = Union[str, os.PathLike[str]]
ArrayLike = npt.ArrayLike
F64 = npt.NDArray[np.float64]

__version__: str
#: Units of the standard columns: t_s "s", u_m/d_m/x_m/y_m "m", tap "1".
COLUMN_UNITS: Dict[str, str]
#: Effect identifier -> the physics it stands for.
EFFECTS: Dict[str, str]
#: Setup name -> (is a tap, cantilever k in N/m, tip radius in m, recording rate in Hz).
SETUPS: Dict[str, Tuple[bool, float, float, float]]

class ViscoError(ValueError):
    """A refusal; str(e) is the command's `FILE[:ENTRY][:LINE]: reason (fix: ...)`."""

    file: str
    """The file at fault (a recording's `source` for in-memory recordings)."""
    entry: Optional[str]
    """The member of an archive (JPK), if any."""
    line: Optional[int]
    """1-based line of the file (for arrays: of the recording written as CSV)."""
    reason: str
    fix: Optional[str]

class Recording:
    """A recording (shared/spec/recording.md): metadata and named columns."""

    metadata: Dict[str, Any]
    """Contract keys: visco-recording, mode, sample_rate_hz (Hz), cantilever_k_n_per_m (N/m),
    cantilever_c_ns_per_m (N*s/m), cantilever_m_kg (kg), cantilever_f0_hz (Hz), cantilever_q,
    tip_radius_m (m), deflection_noise_m (m); others as text."""
    columns: Dict[str, np.ndarray]
    """Name -> 1-D array in file order: t_s (s), u_m (m), d_m (m), x_m, y_m (m), tap (int64),
    extras (unit from the suffix)."""
    source: str
    curve: int
    def __init__(
        self,
        metadata: Mapping[str, Any],
        columns: Mapping[str, ArrayLike],
        source: str = ...,
        curve: int = ...,
    ) -> None: ...
    @property
    def t(self) -> F64:
        """Time, s."""
    @property
    def u(self) -> F64:
        """Commanded base position U, m (z up)."""
    @property
    def d(self) -> F64:
        """Deflection D, m (negative when the sample pushes the tip up)."""
    @property
    def x(self) -> Optional[F64]:
        """Lateral X, m."""
    @property
    def y(self) -> Optional[F64]:
        """Lateral Y, m."""
    @property
    def tap(self) -> Optional[npt.NDArray[np.int64]]: ...
    @property
    def extras(self) -> Dict[str, F64]: ...
    @property
    def mode(self) -> str: ...
    def units(self) -> Dict[str, str]: ...
    def __len__(self) -> int: ...
    @classmethod
    def from_arrays(
        cls,
        t: ArrayLike,
        u: ArrayLike,
        d: ArrayLike,
        *,
        mode: str = ...,
        spring_constant: float,
        tip_radius: float,
        sample_rate: Optional[float] = ...,
        damping: Optional[float] = ...,
        mass: Optional[float] = ...,
        resonance: Optional[float] = ...,
        quality_factor: Optional[float] = ...,
        deflection_noise: Optional[float] = ...,
        x: Optional[ArrayLike] = ...,
        y: Optional[ArrayLike] = ...,
        tap: Optional[ArrayLike] = ...,
        extra: Optional[Mapping[str, ArrayLike]] = ...,
        metadata: Optional[Mapping[str, Any]] = ...,
        source: str = ...,
    ) -> Recording:
        """t in s, u and d in m, spring_constant in N/m, tip_radius in m, sample_rate in Hz,
        damping in N*s/m, mass in kg, resonance in Hz, deflection_noise in m."""
    def write(self, path: PathLike) -> None: ...
    def check(self) -> None: ...

class Report(Dict[str, Any]):
    """The command's JSON report as a dict; `series`: per-sample numpy arrays."""

    series: Dict[str, Any]
    def __init__(self, data: Mapping[str, Any], series: Mapping[str, Any]) -> None: ...
    def to_dict(self) -> Dict[str, Any]: ...

class Simulation:
    recording: Recording
    truth_d_m: F64
    """Noise-free D with the effects, m (the simulator's truth)."""
    clean_d_m: F64
    """Noise-free D without them, m."""
    noise_m: float
    """RMS noise of D, m."""
    effects: List[Dict[str, Any]]
    """{"effect", "parameters" (SI), "peak_over_noise"} per effect."""
    setup: str

def read(
    path: PathLike,
    *,
    curve: Optional[int] = ...,
    spring_constant: Optional[float] = ...,
    sensitivity: Optional[float] = ...,
    tip_radius: Optional[float] = ...,
    sample_rate: Optional[float] = ...,
) -> Recording:
    """spring_constant N/m, sensitivity m per raw unit (m/V, m/nA), tip_radius m,
    sample_rate Hz."""

def read_all(
    path: PathLike,
    *,
    spring_constant: Optional[float] = ...,
    sensitivity: Optional[float] = ...,
    tip_radius: Optional[float] = ...,
    sample_rate: Optional[float] = ...,
) -> Dict[int, Recording]: ...
def identify(
    rec: Union[Recording, PathLike],
    *,
    regressor: str = ...,
    element_pitch: float = ...,
    lattice_origin: Optional[Sequence[float]] = ...,
    readout: float = ...,
    pixels: int = ...,
    lines: Optional[int] = ...,
    contact_sigma: float = ...,
    out_dir: Optional[PathLike] = ...,
) -> Report:
    """element_pitch m, lattice_origin m, readout s."""

def diagnose(
    rec: Union[Recording, PathLike],
    *,
    alpha: float = ...,
    effects: Optional[Iterable[str]] = ...,
    max_effects: int = ...,
    progress: Optional[Callable[[str], None]] = ...,
) -> Report: ...
def simulate(
    setup: str = ...,
    effects: Iterable[str] = ...,
    *,
    magnitude: float = ...,
    seed: int = ...,
    noise: bool = ...,
) -> Simulation:
    """magnitude: each effect's largest |delta D| in multiples of the noise RMS."""
