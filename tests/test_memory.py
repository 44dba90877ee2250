"""The garbage collector's settings after start-up (``service.runtime.memory``)."""

from __future__ import annotations

import gc
import weakref

from service.runtime.memory import GEN1_COLLECTIONS_PER_FULL, freeze_start_up_objects


def test_start_up_freezes_what_is_alive_and_makes_full_collections_rarer() -> None:
    before = gc.get_threshold()
    try:
        alive = object.__new__(type("Alive", (), {}))
        freeze_start_up_objects()
        young, middle, full = gc.get_threshold()
        # CPython's default is 10 (a service started earlier in this process may have set it).
        assert (young, middle) == before[:2] and full == GEN1_COLLECTIONS_PER_FULL > 10
        assert gc.get_freeze_count() > 0 and not any(o is alive for o in gc.get_objects())
    finally:
        gc.unfreeze()
        gc.set_threshold(*before)


class _Node:
    next: object = None


def test_cyclic_garbage_made_later_is_still_collected() -> None:
    before = gc.get_threshold()
    try:
        freeze_start_up_objects()
        node = _Node()
        node.next = node  # a cycle: reference counting alone never frees it
        gone = weakref.ref(node)
        del node
        gc.collect()
        assert gone() is None
    finally:
        gc.unfreeze()
        gc.set_threshold(*before)
