"""feedloop from Python.

A thin binding of feedloop's Rust crates: the same trace reader, simulator and model workbench
the ``feedloop`` command runs, with results as Python objects.

- ``read_trace(path)`` and ``simulate(job_path)`` return a :class:`Trace`:
  ``trace["x.load"]`` is a float64 numpy array, ``trace.columns``, ``trace.period_s``,
  ``trace.to_pandas()``.
- ``compare``, ``diagnose`` and ``fit`` take a trace (a path or a :class:`Trace`) and a model (a
  path or the model's TOML text) and return result objects whose attributes are the fields of the
  JSON the CLI prints with ``--json``; in Jupyter they show the report's tables.

Errors are :class:`FeedloopError` with the CLI's messages. The Rust work runs without the
interpreter lock: threads and process pools run in parallel.
"""

from __future__ import annotations

import html as _html
import json as _json
import os as _os
from typing import Any, Iterable, Optional, Sequence, Union

from . import _feedloop
from ._feedloop import FeedloopError, Trace

__all__ = [
    "FeedloopError",
    "Trace",
    "read_trace",
    "simulate",
    "compare",
    "diagnose",
    "fit",
    "Comparison",
    "Diagnosis",
    "FitResult",
]

PathLike = Union[str, "os.PathLike[str]"]


def read_trace(path: PathLike) -> Trace:
    """Reads a trace file (format v1): every column, validated as the CLI validates it."""
    return _feedloop.read_trace(_os.fspath(path))


def simulate(job: PathLike) -> Trace:
    """Simulates a job file in one process (``feedloop sim``) and returns its trace."""
    return _feedloop.simulate(_os.fspath(job))


def _trace_arg(trace: Any) -> Any:
    if isinstance(trace, Trace):
        return trace
    return _os.fspath(trace)


def _model_arg(model: Any) -> str:
    if isinstance(model, str):
        return model
    return _os.fspath(model)


class _Result:
    """A workbench result: the JSON's fields as attributes (``result.json`` holds them all)."""

    _title = "feedloop"

    def __init__(self, json_text: str, html: str):
        self.json: dict = _json.loads(json_text)
        self._html = html

    def __getattr__(self, name: str) -> Any:
        # only called when normal lookup fails: the JSON's fields
        try:
            return self.__dict__["json"][name]
        except KeyError:
            raise AttributeError(
                f"{type(self).__name__} has no attribute {name!r} "
                f"(fields: {', '.join(self.__dict__.get('json', {}))})"
            ) from None

    def __dir__(self) -> Iterable[str]:
        return list(super().__dir__()) + list(self.json)

    def _repr_html_(self) -> str:
        return self._html

    def _figures(self) -> str:
        rows = "".join(
            f"<tr><th style='text-align:left'>{_html.escape(k)}</th>"
            f"<td style='text-align:left'>{_html.escape(_short(v))}</td></tr>"
            for k, v in self.json.items()
            if not isinstance(v, (list, dict))
        )
        return f"<table>{rows}</table>"


def _short(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.6g}"
    return str(v)


class Comparison(_Result):
    """What ``feedloop compare --json`` prints: ``equation_nrmse_pct``,
    ``window_sim_nrmse_pct``, ``free_sim_nrmse_pct``, ... ; the report in Jupyter."""

    def __repr__(self) -> str:
        return (
            f"<feedloop.Comparison equation NRMSE {self.json.get('equation_nrmse_pct')} %, "
            f"windowed simulation NRMSE {self.json.get('window_sim_nrmse_pct')} %>"
        )


class Diagnosis(_Result):
    """What ``feedloop diagnose --json`` prints: ``candidates`` (a list of dicts with
    ``effect``, ``class``, ``significant``, ...), ``verdict``, ...; with ``auto=True`` the guided
    loop's ``steps`` and the final model's text in ``model_text``."""

    def __init__(self, json_text: str, html: str, model_text: Optional[str]):
        super().__init__(json_text, html)
        self.model_text = model_text

    @property
    def top(self) -> Optional[dict]:
        """The first candidate (the most likely cause), or None."""
        c = self.json.get("candidates") or self.json.get("last", {}).get("candidates") or []
        return c[0] if c else None

    def __repr__(self) -> str:
        t = self.top
        return f"<feedloop.Diagnosis top {t['effect'] if t else None!r}: {self.json.get('verdict', '')}>"


class FitResult(_Result):
    """What ``feedloop fit --json`` prints: ``added``, ``params``, ``error_before`` and
    ``error_after`` (dicts of the error figures: ``equation_nrmse_pct``,
    ``window_sim_nrmse_pct``, ...), ``warnings``; ``model_text`` is the fitted model file's text
    (``write(path)`` writes it)."""

    def __init__(self, json_text: str, model_text: str):
        super().__init__(json_text, "")
        self.model_text = model_text

    def write(self, path: PathLike) -> None:
        """Writes the fitted model file."""
        with open(path, "w", encoding="utf-8") as f:
            f.write(self.model_text)

    def _repr_html_(self) -> str:
        b, a = self.json.get("error_before", {}), self.json.get("error_after", {})
        keys = [k for k in b if isinstance(b.get(k), (int, float)) or b.get(k) is None]
        rows = "".join(
            f"<tr><td>{_html.escape(k)}</td><td>{_short(b.get(k))}</td><td>{_short(a.get(k))}</td></tr>"
            for k in keys
        )
        params = "".join(
            f"<tr><td>{_html.escape(str(k))}</td><td>{_short(v)}</td></tr>"
            for k, v in (self.json.get("params") or {}).items()
        )
        return (
            "<h4>fit: errors before and after</h4>"
            f"<table><tr><th>figure</th><th>before</th><th>after</th></tr>{rows}</table>"
            f"<h4>fitted parameters</h4><table>{params}</table>"
        )

    def __repr__(self) -> str:
        b = self.json.get("error_before", {}).get("equation_nrmse_pct")
        a = self.json.get("error_after", {}).get("equation_nrmse_pct")
        return f"<feedloop.FitResult equation NRMSE {_short(b)} % -> {_short(a)} %>"


def compare(
    trace: Any,
    model: Any,
    *,
    axis: Optional[str] = None,
    cutoff_hz: Optional[float] = None,
    raw_torque: bool = False,
    window_s: float = 0.05,
    added_input: Optional[str] = None,
) -> Comparison:
    """Compares a model with a trace (``feedloop compare``)."""
    j, h = _feedloop.compare_json(
        _trace_arg(trace),
        _model_arg(model),
        axis=axis,
        cutoff_hz=cutoff_hz,
        raw_torque=raw_torque,
        window_s=window_s,
        added_input=added_input,
    )
    return Comparison(j, h)


def diagnose(
    trace: Any,
    model: Any,
    auto: bool = False,
    *,
    max_steps: int = 6,
    dictionary_columns: Optional[Sequence[str]] = None,
    axis: Optional[str] = None,
    cutoff_hz: Optional[float] = None,
    raw_torque: bool = False,
    window_s: float = 0.05,
    added_input: Optional[str] = None,
    report: bool = False,
) -> Diagnosis:
    """Ranks the candidate causes of the misfit (``feedloop diagnose``); with ``auto=True`` the
    guided loop (``diagnose --auto``). With ``report=True`` the HTML shown in Jupyter is the whole
    report (it then simulates the model, as ``diagnose --out`` does)."""
    j, h, text = _feedloop.diagnose_json(
        _trace_arg(trace),
        _model_arg(model),
        auto_loop=auto,
        max_steps=max_steps,
        dictionary_columns=list(dictionary_columns or []),
        axis=axis,
        cutoff_hz=cutoff_hz,
        raw_torque=raw_torque,
        window_s=window_s,
        added_input=added_input,
        report_html=report,
    )
    return Diagnosis(j, h, text)


def fit(
    trace: Any,
    model: Any,
    add: Sequence[str] = (),
    *,
    free: Optional[Sequence[str]] = None,
    axis: Optional[str] = None,
    cutoff_hz: Optional[float] = None,
    raw_torque: bool = False,
    window_s: float = 0.05,
    added_input: Optional[str] = None,
) -> FitResult:
    """Adds effects and refits (``feedloop fit``)."""
    if isinstance(add, str):
        add = [a for a in add.split(",") if a]
    j, text = _feedloop.fit_json(
        _trace_arg(trace),
        _model_arg(model),
        list(add),
        free=None if free is None else list(free),
        axis=axis,
        cutoff_hz=cutoff_hz,
        raw_torque=raw_torque,
        window_s=window_s,
        added_input=added_input,
    )
    return FitResult(j, text)
