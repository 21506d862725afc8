"""One helper that turns a frozen dataclass into a JAX pytree.

Every field is a pytree child (traced under jit, batched under vmap). A field
holding ``None`` is an empty subtree, which is how 2D states leave out ``quat``
and 3D states leave out ``angle``.
"""

from __future__ import annotations

import dataclasses

import jax


def pytree_dataclass(cls):
    """Decorate ``cls`` as a frozen dataclass registered as a JAX pytree.

    The class also gains ``replace(**changes)``, a shorthand for
    :func:`dataclasses.replace`.
    """
    cls = dataclasses.dataclass(frozen=True)(cls)
    names = [field.name for field in dataclasses.fields(cls)]
    jax.tree_util.register_dataclass(cls, data_fields=names, meta_fields=[])
    cls.replace = lambda self, **changes: dataclasses.replace(self, **changes)
    return cls
