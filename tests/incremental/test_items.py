"""The content-addressed item store (recon.items)."""

from __future__ import annotations

import numpy as np

from recon.items import ItemStore, item_key


def test_key_is_canonical_and_changes_with_what_determines_the_item():
    assert item_key({"a": 1, "b": [1, 2]}) == item_key({"b": [1, 2], "a": 1})
    assert item_key({"a": 1, "b": [1, 2]}) != item_key({"a": 1, "b": [2, 1]})


def test_an_item_is_found_whole_and_linked_not_symlinked(tmp_path):
    store = ItemStore(tmp_path / "items", ".npz")
    key = item_key({"photo": "x"})
    assert store.get(key) is None and not store.link(key, tmp_path / "out" / "a.npz")
    source = tmp_path / "made.npz"
    np.savez(source, keypoints=np.arange(6.0))
    store.put(key, source)
    dest = tmp_path / "out" / "a.npz"
    assert store.link(key, dest)
    assert not dest.is_symlink() and dest.read_bytes() == source.read_bytes()
    assert dest.stat().st_ino == store.path(key).stat().st_ino  # a hard link: no copy
    with np.load(dest, allow_pickle=False) as data:
        assert data["keypoints"].tolist() == list(range(6))


def test_an_item_changed_after_it_was_stored_is_not_handed_out(tmp_path):
    """A stage output hard-linked to an item and edited in place edits the item: the store's record
    of its content catches it, so the item is computed again rather than reused."""
    store = ItemStore(tmp_path / "items", ".bin")
    key = item_key("k")
    store.write(key, lambda p: p.write_bytes(b"0123456789"))
    assert store.get(key) == store.path(key)
    with open(store.path(key), "r+b") as f:  # same size, other content
        f.write(b"X")
    assert store.get(key) is None
    store.path(key).unlink()
    assert store.get(key) is None
    store.write(key, lambda p: p.write_bytes(b"new"))  # computed again: replaced
    assert store.get(key) is not None and store.path(key).read_bytes() == b"new"


def test_a_half_written_item_leaves_nothing(tmp_path):
    store = ItemStore(tmp_path / "items", ".bin")

    def fails(path):
        path.write_bytes(b"half")
        raise OSError("disk full")

    try:
        store.write(item_key(1), fails)
    except OSError:
        pass
    assert store.get(item_key(1)) is None and list((tmp_path / "items").iterdir()) == []


def test_clean_keeps_items_and_counts_only_the_bytes_it_frees(tmp_path):
    """`recon clean` drops stage outputs the config no longer uses but keeps the items (what added
    photos reuse); a depth map that is both an output and an item frees nothing until `--all`."""
    from recon.pipeline import clean
    from recon.workspace import Workspace

    ws = Workspace(tmp_path / "ws")
    old = ws.output_dir("mvs", "0" * 64)
    old.mkdir(parents=True)
    (old / "only_here.bin").write_bytes(b"x" * 1000)
    store = ItemStore(ws.items_dir("mvs"), ".bin")
    key = item_key({"view": 1})
    store.write(key, lambda p: p.write_bytes(b"d" * 5000))
    assert store.link(key, old / "depth.bin")

    assert clean(None, ws.root) == (1, 1000)  # the output's own file; the depth map lives on as an item
    assert not old.exists() and store.get(key) is not None
    removed, freed = clean(None, ws.root, everything=True)
    assert removed == 0 and freed >= 5000 and not ws.items_dir("mvs").exists()
