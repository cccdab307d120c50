"""The store as xarray reads it: codes turned into names.

``status`` and ``step`` are stored as small integer codes with CF ``flag_values`` and
``flag_meanings`` (and the code outside them named by an attribute of its own, such as
``not_computed=-1``).  One call gives names instead::

    import xarray as xr
    from pipeline.dataset import with_names

    scores = with_names(xr.open_zarr("data/store.zarr", group="scores"))
    scores.status.to_series().value_counts()

Only xarray and numpy are needed; the pipeline's heavy parts are not imported.
"""

from __future__ import annotations

import numpy as np

#: Attributes of a flag variable that are not names of a code.
_CF_ATTRS = {"flag_values", "flag_meanings", "long_name", "units", "description",
             "coordinates", "_FillValue"}


def code_names(attrs: dict) -> dict[int, str]:
    """Code -> name from a variable's CF flag attributes (and its named special codes)."""
    names = dict(zip((int(v) for v in attrs["flag_values"]), attrs["flag_meanings"].split(),
                     strict=True))
    for key, value in attrs.items():
        if key not in _CF_ATTRS and isinstance(value, int | np.integer):
            names.setdefault(int(value), key)
    return names


def with_names(data):
    """``data`` (an xarray Dataset or DataArray) with every flag variable's codes replaced
    by their names (strings); other variables and all attributes are kept."""
    if hasattr(data, "data_vars"):
        return data.assign({name: with_names(var) for name, var in data.data_vars.items()
                            if _is_flag(var)})
    if not _is_flag(data):
        return data
    names = code_names(data.attrs)
    codes = np.array(sorted(names))
    table = np.array([names[c] for c in codes])
    values = np.asarray(data.values)
    where = np.clip(np.searchsorted(codes, values), 0, len(codes) - 1)
    known = codes[where] == values
    named = np.where(known, table[where], values.astype(str))
    special = set(names.values()) | {"flag_values", "flag_meanings"}
    attrs = {k: v for k, v in data.attrs.items() if k not in special}
    return data.copy(data=named).assign_attrs(attrs)


def _is_flag(var) -> bool:
    return "flag_values" in var.attrs and "flag_meanings" in var.attrs
