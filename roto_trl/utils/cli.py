"""``key=value`` command lines for the small tools (record, evaluate), with one-line errors, and the
checks of config values they and ``train.py`` share."""

from __future__ import annotations

import re

from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import ConfigKeyError


def parse_key_values(prog: str, argv: list[str], defaults: dict, example: str, usage: str = "") -> DictConfig:
    """``argv`` (``key=value`` each, as Hydra's overrides) merged over ``defaults``.

    A default of ``"???"`` is required; a dict-valued default (e.g. ``env``) takes any sub-key
    (``env.episode_steps=100``), which its consumer checks. ``-h`` or ``--help`` prints ``usage``
    (the program's docstring, which documents every key) and exits 0. Bad input exits with one
    line naming the problem and ``example``.
    """
    if any(a in ("-h", "--help") for a in argv):
        print(usage.strip() or f"usage: {prog} key=value ...; e.g. {example}")
        raise SystemExit(0)
    bad = [a for a in argv if "=" not in a]
    if bad:
        raise SystemExit(f"{prog}: arguments are key=value, got {bad}; e.g. {example}")
    cfg = OmegaConf.create(defaults)
    OmegaConf.set_struct(cfg, True)
    for key, value in defaults.items():
        if isinstance(value, dict):
            OmegaConf.set_struct(cfg[key], False)
    try:
        cfg = OmegaConf.merge(cfg, OmegaConf.from_dotlist(argv))
    except ConfigKeyError as err:
        raise SystemExit(f"{prog}: unknown key {err.key!r}; valid: {sorted(defaults)}") from None
    missing = [key for key in defaults if OmegaConf.is_missing(cfg, key)]
    if missing:
        raise SystemExit(f"{prog}: give {' '.join(k + '=...' for k in missing)}; e.g. {example}")
    return cfg


_UNITS = {"": 1, "k": 1_000, "M": 1_000_000, "G": 1_000_000_000}
_FRAMES = re.compile(r"(\d+(?:\.\d+)?(?:e\d+)?)([kMG]?)")


def frame_count(value, key: str) -> int:
    """A frame count written as a user would: ``2000000``, ``2_000_000``, ``2e6``, ``2M``, ``500k``
    (suffixes k, M, G), as a positive int; a one-line ``ValueError`` naming ``key`` otherwise."""
    if isinstance(value, int | float) and not isinstance(value, bool):
        text = repr(value)
    elif isinstance(value, str):
        text = value.strip().replace("_", "")
    else:
        text = ""
    match = _FRAMES.fullmatch(text.removesuffix(".0")) if text else None
    frames = round(float(match[1]) * _UNITS[match[2]]) if match else 0
    if frames < 1 or (match and float(match[1]) * _UNITS[match[2]] != frames):
        example = "such as 2M, 2_000_000 or 2e6"
        raise ValueError(f"{key} must be a positive whole number of frames {example}, got {value!r}")
    return frames


def frames_label(frames: int) -> str:
    """``2_500_000`` -> ``"2.5M"``, ``400_000`` -> ``"400k"`` (``frame_count`` reads them back)."""
    for suffix, unit in (("G", 1e9), ("M", 1e6), ("k", 1e3)):
        if frames >= unit:
            return f"{frames / unit:g}{suffix}"
    return str(frames)


def is_number(value) -> bool:
    """An int or float from a config (a YAML ``true`` is a bool, not a number)."""
    return isinstance(value, int | float) and not isinstance(value, bool)


def check_int(prog: str, cfg: DictConfig, key: str, minimum: int, *, optional: bool = False) -> None:
    """Exit with one line naming ``key`` unless ``cfg[key]`` is an integer >= ``minimum`` (or
    null when ``optional``)."""
    value = cfg[key]
    if value is None and optional:
        return
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        null = " or null" if optional else ""
        raise SystemExit(f"{prog}: {key} must be an integer >= {minimum}{null}, got {value!r}")
