"""``store.path`` values: local paths (resolved through links), file:// URLs, URLs of
fsspec filesystems, and the one-line refusals of anything else."""

import pytest

from pipeline.store import StoreError
from pipeline.store.location import URL, locate


def test_local_paths_and_file_urls_resolve_to_the_same_place(tmp_path):
    real = tmp_path / "real.zarr"
    real.mkdir()
    (tmp_path / "link.zarr").symlink_to(real)
    assert locate(tmp_path / "link.zarr").local == real
    assert locate(f"file://{real}").local == real
    assert str(locate(real)) == str(real)


def test_urls_keep_their_text_and_read_like_paths():
    where = locate("s3://bucket/runs/x.zarr/", {"anon": False})
    assert where.local is None and str(where) == "s3://bucket/runs/x.zarr"
    assert where.name == "x.zarr" and where.storage_options == {"anon": False}
    assert isinstance(where.path, URL) and where.path / "scores" == "s3://bucket/runs/x.zarr/scores"
    assert str(where.sibling(".lock")) == "s3://bucket/runs/x.zarr.lock"


@pytest.mark.parametrize("path, words", [
    ("nosuch://bucket/x.zarr", "unknown scheme 'nosuch'"),
    ("s3:///x.zarr", "needs a bucket"),
    ("file://otherhost/x.zarr", "file URLs name a local path"),
])
def test_bad_locations_are_refused_naming_them(path, words):
    with pytest.raises(StoreError, match=words) as info:
        locate(path)
    assert path in str(info.value) and "\n" not in str(info.value)


def test_the_endpoint_comes_from_the_aws_environment(monkeypatch):
    monkeypatch.setenv("AWS_ENDPOINT_URL", "http://127.0.0.1:9000")
    assert locate("s3://b/x.zarr").options() == {"endpoint_url": "http://127.0.0.1:9000"}
    configured = locate("s3://b/x.zarr", {"endpoint_url": "http://elsewhere"})
    assert configured.options() == {"endpoint_url": "http://elsewhere"}
