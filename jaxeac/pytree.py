"""Frozen dataclasses that are JAX pytrees (gymnax/flax-struct style, no extra dependency)."""

from __future__ import annotations

import dataclasses
from typing import TypeVar

import jax

T = TypeVar("T")


def pytree_dataclass(cls: type[T]) -> type[T]:
    """Make `cls` a frozen dataclass registered as a pytree.

    Fields are array leaves unless declared with ``static_field()``; update with
    ``.replace(...)`` (never in place).
    """
    cls = dataclasses.dataclass(frozen=True)(cls)
    cls.replace = lambda self, **changes: dataclasses.replace(self, **changes)  # type: ignore[attr-defined]
    return jax.tree_util.register_dataclass(cls)


def static_field(**kwargs):
    """A dataclass field that is part of the pytree structure, not a leaf."""
    return dataclasses.field(metadata={"static": True}, **kwargs)
