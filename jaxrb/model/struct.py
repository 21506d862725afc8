"""One helper that turns a frozen dataclass into a JAX pytree.

Every field is a pytree child (traced under jit, batched under vmap). A field
holding ``None`` is an empty subtree, which is how 2D states leave out ``quat``
and 3D states leave out ``angle``.
"""

from __future__ import annotations

import dataclasses

import jax


def _replace(self, **changes):
    """A copy with some fields replaced, e.g. ``state.replace(pos=new_pos)``.

    Args:
        **changes: field name -> new value (arrays keep the field's documented
            shape, e.g. ``pos`` (n, dim)).

    Returns:
        A new instance of the same class; ``self`` is unchanged.
    """
    return dataclasses.replace(self, **changes)


def pytree_dataclass(cls):
    """Decorate ``cls`` as a frozen dataclass registered as a JAX pytree.

    The class also gains ``replace(**changes)``, a shorthand for
    :func:`dataclasses.replace`.

    Args:
        cls: the class to decorate; its annotated fields become pytree children.

    Returns:
        ``cls``, now a frozen dataclass and a registered pytree.
    """
    cls = dataclasses.dataclass(frozen=True)(cls)
    names = [field.name for field in dataclasses.fields(cls)]
    jax.tree_util.register_dataclass(cls, data_fields=names, meta_fields=[])
    if "replace" not in cls.__dict__:  # a class may check its own changes (Params)
        cls.replace = _replace
    return cls
