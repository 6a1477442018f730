"""Integer wire fields saturated to their MAVLink types' ranges, read from pymavlink's own message
definitions: the one place where `link.wire` bounds them (see its module docstring).
"""

from __future__ import annotations

import functools
import operator
import struct

_INT_CODE = {"int8_t": "b", "uint8_t": "B", "int16_t": "h", "uint16_t": "H"}
_INT_CODE |= {"int32_t": "i", "uint32_t": "I", "int64_t": "q", "uint64_t": "Q"}
"""struct's code of each integer type (standard sizes): it packs exactly the values of its _INT_RANGE."""
_INT_RANGE = {
    "int8_t": (-(2**7), 2**7 - 1),
    "uint8_t": (0, 2**8 - 1),
    "int16_t": (-(2**15), 2**15 - 1),
    "uint16_t": (0, 2**16 - 1),
    "int32_t": (-(2**31), 2**31 - 1),
    "uint32_t": (0, 2**32 - 1),
    "int64_t": (-(2**63), 2**63 - 1),
    "uint64_t": (0, 2**64 - 1),
}


def saturating(message_class):
    """Decorate a `*_fields` function of `message_class`: every scalar integer field of its result is
    saturated to the range of the field's MAVLink type, as pymavlink's message definition gives it.
    The one place where integer wire fields are bounded."""
    limits = tuple(
        (name, *_INT_RANGE[kind])
        for name, kind in zip(message_class.fieldnames, message_class.fieldtypes, strict=True)
        if kind in _INT_RANGE
    )

    def decorate(fields_of):
        @functools.wraps(fields_of)
        def saturated(*args, **kwargs) -> dict:
            out = fields_of(*args, **kwargs)
            for name, lo, hi in limits:
                v = out.get(name, 0)  # (an extension field left out takes pymavlink's default, 0)
                if v < lo:
                    out[name] = lo
                elif v > hi:
                    out[name] = hi
            return out

        return saturated

    return decorate


def saturating_args(message_class):
    """`saturating` for an `*_args` function of `message_class`, whose result is the message's fields
    as a list in the order of its definition (the order of pymavlink's `<message>_encode` and
    `<message>_send` arguments): the same bounds, applied by position. The messages of every
    simulation step are built this way (a list, one call to pymavlink), and their `*_fields` dicts
    from the same function (`fields_from_args`)."""
    limits = tuple((i, *_INT_RANGE[kind]) for i, kind in enumerate(message_class.fieldtypes) if kind in _INT_RANGE)
    # Every simulation step, all of them at once: struct packs each integer only within its type's
    # range (the ranges of _INT_RANGE), so a pack that succeeds says none needs bounding. Anything
    # else (a value out of range, a NaN, a non-integer) takes the field-by-field check.
    if limits:
        fits = struct.Struct("<" + "".join(_INT_CODE[message_class.fieldtypes[i]] for i, _, _ in limits)).pack
        integers = operator.itemgetter(*(i for i, _, _ in limits))
        if len(limits) == 1:
            integers = (lambda get: lambda out: (get(out),))(integers)

    def decorate(args_of):
        @functools.wraps(args_of)
        def saturated(*args, **kwargs) -> list:
            out = args_of(*args, **kwargs)
            if limits:
                try:
                    fits(*integers(out))
                    return out
                except struct.error:
                    pass
            for i, lo, hi in limits:
                v = out[i]
                if v < lo:
                    out[i] = lo
                elif v > hi:
                    out[i] = hi
            return out

        return saturated

    return decorate


def fields_from_args(message_class, args_of, doc: str):
    """The keyword-argument form of an `*_args` function: {field name: value}."""
    names = message_class.fieldnames

    @functools.wraps(args_of)
    def fields(*args, **kwargs) -> dict:
        return dict(zip(names, args_of(*args, **kwargs), strict=True))

    fields.__doc__ = doc
    return fields
