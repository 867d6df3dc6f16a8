"""--config FILE, then each --set (and a command's own flags), into the parameters the library takes.

An error in the file's own values names the file; one in a --set value is named by the option.
"""

from __future__ import annotations

from pathlib import Path

from ..config import check_params, naming, parse_set_option, read_config_file
from ..sim.config import SimConfig, apply_overrides


def simulation_config(config_file: Path | None = None, set_items: tuple[str, ...] = (), *, duration: float | None = None,
                      seed: int | None = None, speed: float | None = None) -> SimConfig:
    """The recording's parameters: the defaults, then --config FILE, then the options given (--duration,
    --seed, --speed; None: not given), then each --set; each checked against its range."""
    cfg = SimConfig()
    if config_file:
        with naming(config_file):  # each of the file's values checked against its range, so that an error names it
            cfg = check_params(apply_overrides(cfg, read_config_file(config_file)))
    flags: dict[str, dict] = {"run": {}, "robot": {}}
    if duration is not None:
        flags["run"]["duration"] = duration
    if seed is not None:
        flags["run"]["seed"] = seed
    if speed is not None:
        flags["robot"]["speed"] = speed
    cfg = apply_overrides(cfg, flags)
    return apply_overrides(cfg, parse_set_option(set_items)).validate()


def frontend_params(config_file: Path | None, set_items: tuple[str, ...]):
    """--config FILE, then each --set; an error in the file's own values names the file."""
    from ..frontend.params import load_frontend_params

    file_values = read_config_file(config_file) if config_file else None
    with naming(config_file):
        load_frontend_params(file_values)
    return load_frontend_params(file_values, parse_set_option(set_items))
