"""Checks of the torch-side arguments: a tensor, on the CPU, of an accepted dtype. Every
failure is a ValueError naming the argument; shapes and values are then checked by
:mod:`glraster.diff.layout` on the NumPy view, with the same names."""

from __future__ import annotations

import numpy as np
import torch

FLOAT_DTYPES = (torch.float32, torch.float64)
INT_DTYPES = (torch.int32, torch.int64)


def _names(dtypes) -> str:
    return " or ".join(str(d) for d in dtypes)


def tensor(name: str, value, dtypes) -> torch.Tensor:
    """``value`` itself, once it is a CPU tensor of one of ``dtypes``."""
    if not isinstance(value, torch.Tensor):
        raise ValueError(f"{name} must be a torch.Tensor, got {type(value).__name__}")
    if value.device.type != "cpu":
        raise ValueError(f"{name} must be on the CPU (glraster.torch reads tensors back to "
                         f"host memory), got device {value.device}")
    if value.layout != torch.strided:
        raise ValueError(f"{name} must be a dense (strided) tensor, got layout {value.layout}")
    if value.dtype not in dtypes:
        raise ValueError(f"{name} must have dtype {_names(dtypes)}, got {value.dtype}")
    return value


def numpy(value: torch.Tensor) -> np.ndarray:
    """A C-contiguous NumPy array of a CPU tensor's values (no copy when already so)."""
    return np.ascontiguousarray(value.detach().numpy())


def same_dtype(name: str, value: torch.Tensor, reference_name: str, dtype) -> None:
    if value.dtype != dtype:
        raise ValueError(f"{name} must have the dtype of {reference_name} ({dtype}), "
                         f"got {value.dtype}: float32 runs on the GPU, float64 through the "
                         "float64 reference, and one op does not mix them")


def flag(name: str, value) -> bool:
    if not isinstance(value, (bool, np.bool_)):
        raise ValueError(f"{name} must be True or False, got {value!r}")
    return bool(value)


def to_torch(array: np.ndarray) -> torch.Tensor:
    """A tensor sharing ``array``'s memory when it is contiguous and writable, else a copy."""
    array = np.asarray(array)
    if not array.flags.c_contiguous or not array.flags.writeable:
        array = np.array(array, order="C", copy=True)
    return torch.from_numpy(array)
