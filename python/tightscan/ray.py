"""Detection inside Ray Data: for users who already hold a ``ray.data.Dataset``.

``tightscan.scan_parquet(..., engine="ray")`` fans a Parquet scan out over Ray itself;
:func:`detect_dataset` is for a dataset built otherwise. It needs
``pip install 'tightscan[ray]'``; the rest of tightscan works without Ray (this module
imports nothing of it).

Point it at a real cluster by connecting first: ``ray.init(address="ray://head:10001")``
(or ``address="auto"`` on a cluster node).
"""

from __future__ import annotations

from typing import Any, Sequence

import pyarrow as pa

from . import _core
from ._api import _passthrough_list
from .config import ConfigLike, as_dict

__all__ = ["detect_dataset"]


def _detect_arrow(batch: pa.Table, config: dict[str, Any] | None, pass_cols: list[str]) -> pa.Table:
    return _core.detect(batch, config, pass_cols)


def detect_dataset(
    dataset: Any,
    config: ConfigLike = None,
    passthrough: Sequence[str] | bool | None = None,
    *,
    batch_size: int | None = None,
) -> Any:
    """Friction changes of every tightening of a ``ray.data.Dataset``, one row per tightening.

    ``map_batches(..., batch_format="pyarrow")`` runs the Rust engine on Arrow batches as
    they are, without a pandas round trip. ``batch_size=None`` hands each block whole, so a
    long-layout tightening is never cut unless a block boundary cuts it (keep a tightening's
    rows in one file); in the nested layout any batch size is safe. The dataset is lazy as
    usual: nothing runs until it is consumed (``write_parquet``, ``take_all`` ...).
    """
    names = list(dataset.schema().names) if passthrough is True else []
    pass_cols = _passthrough_list(passthrough, names)
    return dataset.map_batches(
        _detect_arrow,
        batch_format="pyarrow",
        batch_size=batch_size,
        zero_copy_batch=True,
        fn_kwargs={"config": as_dict(config), "pass_cols": pass_cols},
    )
