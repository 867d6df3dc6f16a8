"""The parameters of a run, and how config files and ``--set`` reach them.

:class:`ProcessParams` is the front end's parameters (:class:`fmcwlog.frontend.params.FrontEndParams`)
with the back end's (:class:`fmcwlog.backend.params.BackendParams`) as one more table,
``backend``. A config file (TOML, YAML or JSON) holds the same structure: the front end's own
parameters at the top level (or in a ``[frontend]`` table), each stage's in its own table
(``[segmentation]``, ``[tracking]``, ``[icp]``, ``[icp.gmmsc]``, ``[backend]``). ``fmcwlog process
--show-config`` prints exactly that as TOML (:func:`params_toml`, each parameter with its unit
and valid range), and ``run.json`` records it under ``params``, so either can be fed back.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..backend.params import BackendParams
from ..config import apply_to_dataclass, naming, parse_set_option, read_config_file, toml_table
from ..errors import ConfigError
from ..frontend.params import FrontEndParams
from ..io.clouds import InputParams


@dataclass(frozen=True)
class ProcessParams(FrontEndParams):
    """Every parameter of ``fmcwlog process``: the front end's, the pose-graph back end's
    (:mod:`fmcwlog.backend`) as ``backend``, and how the scans are read (a 3-D cloud's band about the
    sensor's plane, :mod:`fmcwlog.io.clouds`) as ``inputs``; both methods share them."""

    backend: BackendParams = field(default_factory=BackendParams)
    inputs: InputParams = field(default_factory=InputParams)


def load_params(*sources: dict[str, Any] | None) -> ProcessParams:
    """A run's parameters from parsed config files and ``--set`` tables, applied in order.

    Each source has the structure of :class:`ProcessParams` (``dataclasses.asdict``):
    top-level keys are the front end's own, ``segmentation``/``icp`` are tables. A
    ``[frontend]`` table is accepted as the front end's own keys, and a ``run.json``
    (a table with ``params`` and ``fmcwlog_version``) gives its ``params``.
    """
    params = ProcessParams()
    for source in sources:
        source = dict(source or {})
        if "params" in source and "fmcwlog_version" in source:  # a run.json
            if not isinstance(source["params"], dict):
                raise ConfigError("a run.json's 'params' must be a table of parameters")
            source = dict(source["params"])
        own = source.pop("frontend", {})
        if not isinstance(own, dict):
            raise ConfigError("[frontend] must be a table of parameters")
        params = apply_to_dataclass(params, own, "frontend")
        params = apply_to_dataclass(params, source)
    return params


def params_toml(params: ProcessParams) -> str:
    """Every parameter as TOML (``[frontend]``, then a table per stage: ``[segmentation]``, ``[icp]``, ...), each
    with its unit and range as a comment; :func:`load_params` takes it back unchanged."""
    head = ["# fmcwlog process parameters: every one, with its unit and valid range.",
            "# Use: fmcwlog process LOG --config FILE (or change one with --set TABLE.NAME=VALUE,",
            "# e.g. --set icp.huber_delta=0.04 or --set frontend.voxel_size=0.1).", ""]
    lines = head + toml_table("frontend", params, nested=False)
    for f in dataclasses.fields(params):  # each stage's table: [segmentation], [icp] (and [icp.gmmsc]), ...
        stage = getattr(params, f.name)
        if dataclasses.is_dataclass(stage):
            lines += toml_table(f.name, stage)
    return "\n".join(lines).rstrip() + "\n"


def params_from(config_file: Path | None = None, set_items: tuple[str, ...] = ()) -> ProcessParams:
    """A run's parameters from a config file (TOML, YAML, JSON or a run.json) and then each ``--set``
    item (``TABLE.NAME=VALUE``). Raises :class:`~fmcwlog.errors.ConfigError`: an error in the
    file's own values names the file, one in a ``--set`` item names the item."""
    file_values = read_config_file(config_file) if config_file else None
    with naming(config_file):
        load_params(file_values)
    return load_params(file_values, parse_set_option(set_items))
