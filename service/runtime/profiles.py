"""Named settings profiles: JSON files of server settings, loaded with ``FRT_PROFILE=<name>``.

A profile is ``{"name": ..., "settings": {setting: value, ...}, ...}``; everything besides
``settings`` (e.g. how a calibration chose the values, ``make calibrate``) is provenance the server
ignores. ``FRT_PROFILE`` is a name (``profiles/<name>.json`` in the repository) or a path to such
a file. A profile's settings sit under the environment: ``FRT_GAMMA=0.1`` wins over a profile's
``gamma``; a profile wins over the built-in defaults.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

#: Where named profiles live.
PROFILES_DIR = Path(__file__).resolve().parents[2] / "profiles"
#: The environment variable naming the profile.
PROFILE_ENV = "FRT_PROFILE"


class ProfileError(ValueError):
    """A profile that cannot be found or read, or that names unknown settings."""


def profile_path(name: str) -> Path:
    """``name``'s file: a path if it names a ``.json`` file or has a directory part, else
    ``profiles/<name>.json``."""
    if name.endswith(".json") or os.sep in name or "/" in name:
        return Path(name)
    return PROFILES_DIR / f"{name}.json"


def load_profile(name: str, known: set[str] | None = None) -> dict[str, Any]:
    """The settings of profile ``name``; with ``known``, a :class:`ProfileError` for any setting
    not in it (a misspelt setting must not be ignored silently)."""
    path = profile_path(name)
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise ProfileError(f"{PROFILE_ENV}={name!r}: no profile at {path}") from None
    except (OSError, json.JSONDecodeError) as exc:
        raise ProfileError(f"{PROFILE_ENV}={name!r}: cannot read {path}: {exc}") from None
    settings = data.get("settings") if isinstance(data, dict) else None
    if not isinstance(settings, dict):
        raise ProfileError(f"{PROFILE_ENV}={name!r}: {path} has no 'settings' object")
    if known is not None:
        unknown = sorted(set(settings) - known)
        if unknown:
            raise ProfileError(f"{PROFILE_ENV}={name!r}: unknown settings {unknown} in {path}")
    return settings


def write_profile(path: Path, name: str, settings: dict[str, Any], **provenance: Any) -> Path:
    """Write a profile (``settings`` plus any provenance) to ``path``."""
    path.parent.mkdir(parents=True, exist_ok=True)
    body = {"name": name, "settings": settings, **provenance}
    path.write_text(json.dumps(body, indent=2) + "\n")
    return path
