"""`cec zoo export` writes a bundle (parameters, config, checksums, a card with its evaluation) that loads
from its folder and from an http(s) URL (a real `http.server` on loopback), bounded in size and checked
file by file, and that `cec play` takes as a partner's zoo."""

from __future__ import annotations

import functools
import http.server
import json
import shutil
import threading
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from apps.cli import main
from apps.zoo_build import export_zoo
from cec.agents import bundle
from cec.agents.policy import load_policy
from cec.agents.zoo import load_zoo
from cec.evaluation.results import ARRAY_FIELDS, make_table, write_csv

SEEDS = ("cec758m-s200", "cec758m-s201")


def _results(path: Path) -> Path:
    """A `cec eval` table of the two seeds: self-play 20 and 40 (s200), cross-play 10 and 30, and one episode
    with a partner outside the bundle (60)."""
    rows = [
        ("cec758m-s200", "cec758m-s200", 20.0),
        ("cec758m-s200", "cec758m-s200", 40.0),
        ("cec758m-s200", "cec758m-s201", 10.0),
        ("cec758m-s200", "cec758m-s201", 30.0),
        ("cec758m-s200", "cook", 60.0),
        ("cec758m-s201", "cec758m-s200", 0.0),
    ]
    columns: dict[str, list] = {f: [] for f in ARRAY_FIELDS}
    for i, (a, b, ret) in enumerate(rows):
        values = dict(policy_a=a, algorithm_a="cec", seed_a=200, policy_b=b, algorithm_b="cec", seed_b=201,
                      level="cramped_room", seat=0, episode=i, returns=ret, deliveries=ret / 20,
                      collisions=0.0, shaped_return=0.0, env="overcooked", episode_steps=400,
                      actions="")  # fmt: skip
        for f in ARRAY_FIELDS:
            columns[f].append(values[f])
    return write_csv(make_table(columns), path)


@pytest.fixture(scope="module")
def exported(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("bundle")
    table = _results(root / "results.csv")
    assert main(["zoo", "export", "shipped", *(f"--name={s}" for s in SEEDS), "--out", str(root / "b"),
                 "--results", str(table)]) == 0  # fmt: skip
    return root / "b"


@pytest.fixture
def served(exported: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[tuple[str, Path]]:
    """(URL of a copy of the bundle on a loopback HTTP server, the served folder); downloads cached in tmp."""
    site = tmp_path / "site"
    shutil.copytree(exported, site / "bundle")
    monkeypatch.setenv("CEC_CACHE_DIR", str(tmp_path / "cache"))
    handler = functools.partial(QuietHandler, directory=str(site))
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{server.server_address[1]}/bundle/", site / "bundle"
    finally:
        server.shutdown()
        server.server_close()


class QuietHandler(http.server.SimpleHTTPRequestHandler):
    def log_message(self, format: str, *args: object) -> None:  # noqa: A002 (the base class's name)
        pass


def test_the_export_is_a_self_describing_bundle(exported: Path) -> None:
    index = json.loads((exported / "bundle.json").read_text())
    assert index["format"] == bundle.FORMAT
    assert set(index["files"]) == {"zoo.yaml", "card.md"} | {
        f"{s}/{f}" for s in SEEDS for f in ("state.msgpack", "meta.json")
    }
    for name, item in index["files"].items():
        assert bundle.file_digest(exported / name) == (item["bytes"], item["sha256"])
    meta = json.loads((exported / "cec758m-s200" / "meta.json").read_text())
    assert (
        meta["config"]["algorithm"] == "cec" and meta["metadata"]["params_only"]
    )  # the config travels along
    s200 = index["evaluation"]["policies"]["cec758m-s200"]
    assert (
        s200["episodes"] == 5
        and s200["self-play"]["mean"] == 30.0
        and s200["with the others"]["mean"] == 20.0
    )
    assert s200["with any partner"]["mean"] == pytest.approx(100 / 3)
    card = (exported / "card.md").read_text()
    assert "| cec758m-s200 | 30.0 ± 10.0 (2) | 20.0 ± 10.0 (2) |" in card and "cec758m-s201" in card
    assert [p["name"] for p in index["policies"]] == list(SEEDS)


def test_a_folder_loads_as_its_zoo_and_a_changed_file_is_refused(exported: Path, tmp_path: Path) -> None:
    entries = load_zoo(exported)
    assert [e.name for e in entries] == list(SEEDS)
    assert load_policy(entries[0]).seed == 200
    copy = tmp_path / "copy"
    shutil.copytree(exported, copy)
    state = copy / "cec758m-s201" / "state.msgpack"
    state.write_bytes(state.read_bytes()[:-1] + b"\0")
    with pytest.raises(bundle.BundleError, match=r"cec758m-s201/state.msgpack does not match its SHA-256"):
        load_zoo(copy)


def test_a_url_loads_once_into_the_cache_and_plays_as_the_folder_does(
    served, exported: Path, tmp_path: Path
) -> None:
    url, site = served
    entries = load_zoo(url)
    assert [e.name for e in entries] == list(SEEDS)
    assert all(Path(e.checkpoint).is_relative_to(tmp_path / "cache") for e in entries)
    local = load_policy(load_zoo(exported)[1])
    fetched = load_policy(entries[1])
    assert all(
        np.array_equal(a, b) for a, b in zip(*(jax_leaves(p.params) for p in (local, fetched)), strict=True)
    )
    shutil.rmtree(site / "cec758m-s200")  # the cached copy serves now; the index is still read
    assert [e.name for e in load_zoo(url + "zoo.yaml")] == list(SEEDS)


def jax_leaves(tree: object) -> list:
    import jax

    return jax.tree.leaves(tree)


def test_cec_play_takes_a_bundles_url_as_a_partners_zoo(served) -> None:
    from services.play.config import PartnerSpec
    from services.play.game import load_partner

    url, _ = served
    pool = load_partner(PartnerSpec(name="bundle", zoo=url, group="cec"), Path("/nonexistent"))
    assert sorted(p.name for p in pool.policies) == list(SEEDS)


def _index(site: Path) -> dict:
    return json.loads((site / "bundle.json").read_text())


def _write_index(site: Path, index: dict) -> None:
    (site / "bundle.json").write_text(json.dumps(index))


def test_a_changed_or_larger_file_on_the_server_is_refused_and_nothing_is_cached(
    served, tmp_path: Path
) -> None:
    url, site = served
    state = site / "cec758m-s201" / "state.msgpack"
    data = state.read_bytes()
    state.write_bytes(data[:-1] + b"\0")  # same size, other bytes
    with pytest.raises(
        bundle.BundleError, match="cec758m-s201/state.msgpack does not match its size and SHA-256"
    ):
        load_zoo(url)
    state.write_bytes(data + b"\0" * 1000)  # larger than the index says: read no further than it
    with pytest.raises(bundle.BundleError, match="larger than"):
        load_zoo(url)
    assert not list((tmp_path / "cache" / "bundles").iterdir())  # no bundle, no partial download left


def test_an_index_past_the_bounds_or_naming_files_outside_is_refused_before_any_download(
    served, monkeypatch: pytest.MonkeyPatch
) -> None:
    url, site = served
    index = _index(site)
    monkeypatch.setattr(bundle, "FILE_MAX_BYTES", 1000)  # a policy's parameters are larger
    with pytest.raises(bundle.BundleError, match="`bytes` must be a size of at most 1,000"):
        load_zoo(url)
    monkeypatch.undo()
    for name in ("../outside.txt", "/etc/passwd", "a/../../b"):
        _write_index(site, {**index, "files": {**index["files"], name: {"bytes": 1, "sha256": "0" * 64}}})
        with pytest.raises(bundle.BundleError, match="not a plain relative path"):
            load_zoo(url)
    _write_index(site, {**index, "format": "other"})
    with pytest.raises(bundle.BundleError, match="not a bundle index"):
        load_zoo(url)


def test_a_manifest_naming_a_checkpoint_outside_the_bundle_is_refused(served) -> None:
    url, site = served
    manifest = (
        (site / "zoo.yaml").read_text().replace("checkpoint: cec758m-s200", "checkpoint: /tmp/elsewhere")
    )
    (site / "zoo.yaml").write_text(manifest)
    index = _index(site)
    size, sha = bundle.file_digest(site / "zoo.yaml")
    _write_index(site, {**index, "files": {**index["files"], "zoo.yaml": {"bytes": size, "sha256": sha}}})
    with pytest.raises(bundle.BundleError, match="checkpoint '/tmp/elsewhere' lies outside the bundle"):
        load_zoo(url)


def test_an_unreachable_bundle_names_the_url_and_the_cause(served) -> None:
    url, _ = served
    with pytest.raises(bundle.BundleError, match=r"nowhere/bundle.json answered 404"):
        load_zoo(url.replace("/bundle/", "/nowhere/"))
    assert main(["eval", "--zoo", url.replace("/bundle/", "/nowhere/"), "--levels", "cramped_room"]) == 2


def test_a_results_table_that_plays_none_of_the_policies_is_refused(tmp_path: Path) -> None:
    table = _results(tmp_path / "results.csv")
    with pytest.raises(Exception, match="play none of the exported policies"):
        export_zoo("shipped", tmp_path / "b", names=["cec758m-s202"], results=[table])
    assert not (tmp_path / "b").exists()
