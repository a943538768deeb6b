"""The one resolver for the files that ship beside the code: ``assets/`` and ``conf/``.

In a source checkout (and an editable install) they live at the repository root, next to the
``roto_trl`` package; in a wheel they are packed inside it as ``roto_trl/assets`` and
``roto_trl/conf`` (see ``[tool.hatch.build.targets.wheel.force-include]`` in pyproject.toml).
``TRAIN_SCRIPT`` is where ``train.py`` lies in either layout, for the tools that run it.
"""

from __future__ import annotations

from pathlib import Path

_PACKAGE_DIR = Path(__file__).resolve().parent.parent  # roto_trl/

# the training entry point, for tools that run it as a user would (sweeps, benchmarks, tests)
TRAIN_SCRIPT = _PACKAGE_DIR / "train.py"


def resource_dir(kind: str) -> Path:
    """Return the directory of ``kind`` (``"assets"`` or ``"conf"``), wheel or checkout."""
    if kind not in ("assets", "conf"):
        raise ValueError(f"unknown resource kind {kind!r}; expected 'assets' or 'conf'")
    for candidate in (_PACKAGE_DIR / kind, _PACKAGE_DIR.parent / kind):
        if candidate.is_dir():
            return candidate
    raise FileNotFoundError(
        f"roto_trl cannot find its {kind}/ directory next to {_PACKAGE_DIR}; "
        "reinstall the package (pip install -e .) so that it ships with the code"
    )


def resource_path(kind: str, name: str) -> Path:
    """Return the path of one file under ``assets/`` or ``conf/``, with a clear error if absent."""
    path = resource_dir(kind) / name
    if not path.is_file():
        raise FileNotFoundError(f"roto_trl has no {kind} file {name!r} (looked in {path.parent})")
    return path
