"""The options of ``fdigen discover`` (:class:`DiscoverSettings`) and what it returns
(:class:`DiscoveryResult`)."""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass
class DiscoverSettings:
    """Options of :func:`discover` (defaults in brackets).

    Attributes
    ----------
    fraction : float
        Share of the log used to calibrate [0.6]; the rest validates.
    window : float or None
        Modulating window length [None: from the sample time and the plant's slowest
        time constant, 0.05 s at 1 kHz; see :mod:`fdigen.discover.windows`].
    smooth : float or None
        Savitzky-Golay length of the state reconstruction [None: half the window].
    alpha : float
        Significance of the structure test [1e-3].
    alpha_validation : float
        Level of the held-back confirmation of an effect [0.05].
    consistency : float
        Agreement (in standard deviations) of held-back and calibration estimates
        required when the held-back part alone cannot confirm [3].
    min_structure : float
        Smallest share of structure in an equation's residual that counts [0.05].
    min_gain : float
        Smallest share of the located excess an effect must explain [0.2].
    bic_margin : float
        BIC decrease an effect must bring [10].
    max_effects : int
        At most this many effects [2].
    reinit : float, optional
        Re-initialisation period of the output-error simulation [the longer of 1 s and
        50 samples; a period asked for that is shorter than 50 samples is raised to it,
        with a warning].
    method : {"auto", "output-error"}
        ``"auto"``: the equation test where it can be formed, the output-error loop
        otherwise; ``"output-error"``: the output-error loop always ["auto"].
    command : str
        The fdigen command that runs the discovery, named in the advice it gives
        (``fdigen commission --method output-error``) ["discover"].
    """

    fraction: float = 0.6
    window: float | None = None
    smooth: float | None = None
    alpha: float = 1e-3
    alpha_validation: float = 0.05
    consistency: float = 3.0
    min_structure: float = 0.05
    min_gain: float = 0.2
    bic_margin: float = 10.0
    max_effects: int = 2
    reinit: float | None = None
    method: str = "auto"
    command: str = "discover"


@dataclass
class DiscoveryResult:
    """What :func:`discover` found; :meth:`as_dict` is the ``--json`` output."""

    info: dict = field(default_factory=dict)
    explanation: object = None
    data: object = None

    def as_dict(self) -> dict:
        return dict(self.info)

    @property
    def effects(self) -> list[str]:
        return list(self.info.get("effects", []))
