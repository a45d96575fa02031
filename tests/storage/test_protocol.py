"""The storage seam's shape: one ``Storage`` protocol, two backends that each satisfy it, and the
object store composed over a home-folder store (its cache), never a subclass of it."""

from __future__ import annotations

import inspect
from pathlib import Path

from app.core.config import StoreWaits
from app.storage import LocalStorage, ObjectStorage, Storage

BACKENDS = (LocalStorage, ObjectStorage)


def protocol_methods() -> dict[str, inspect.Signature]:
    """The protocol's methods (what the service may call) and their signatures."""
    return {
        name: inspect.signature(member)
        for name, member in vars(Storage).items()
        if inspect.isfunction(member) and not name.startswith("_")
    }


def test_the_object_store_is_composed_over_the_local_one_not_derived_from_it(
    tmp_path: Path,
) -> None:
    assert not issubclass(ObjectStorage, LocalStorage)
    assert LocalStorage not in ObjectStorage.__mro__
    store = ObjectStorage(
        tmp_path / "home",
        "s3://no-bucket/lab",
        60.0,
        "http://127.0.0.1:9",  # nothing is asked of it here
        waits=StoreWaits(connect_s=1.0, read_s=1.0, attempts=1),
    )
    assert isinstance(store.files, LocalStorage) and not store.files.durable  # its cache
    assert store.files.home == store.home == (tmp_path / "home").resolve()
    assert isinstance(store, Storage) and isinstance(LocalStorage(tmp_path / "local"), Storage)


def test_both_backends_offer_every_protocol_method_with_its_signature() -> None:
    methods = protocol_methods()
    assert {"put", "stage", "install_many", "existing", "collect", "sweep_orphans"} <= set(methods)
    assert len(methods) >= 25
    for backend in BACKENDS:
        for name, signature in methods.items():
            member = getattr(backend, name, None)
            assert callable(member), f"{backend.__name__} lacks {name}"
            assert inspect.signature(member) == signature, f"{backend.__name__}.{name}"
    for attribute in ("home", "grace_s", "remote"):
        assert attribute in Storage.__annotations__


def test_the_protocol_promises_are_written_down() -> None:
    """Each method says what it promises (the docstring callers rely on), and the module
    states the seam's promises."""
    import app.storage.protocol as protocol

    for name in protocol_methods():
        assert (getattr(Storage, name).__doc__ or "").strip(), name
    text = protocol.__doc__ or ""
    for promise in ("Written whole before its row is committed", "claimed", "collector"):
        assert promise in text
