"""Pipeline presets: default.toml sets every parameter to the code's defaults; bad files fail clearly."""

import dataclasses

import pytest

from pcdet.config import (
    PIPELINES_DIR,
    PipelineConfig,
    dump_toml,
    field_docs,
    load_pipeline,
)
from pcdet.errors import InputError


def test_default_preset_equals_code_defaults():
    """default.toml loads to the code's defaults and spells out every field, in its own section."""
    import tomllib

    assert load_pipeline("default") == PipelineConfig()
    doc = tomllib.loads((PIPELINES_DIR / "default.toml").read_text())
    for name in field_docs():
        table = doc
        for part in name.split(".")[:-1]:
            table = table[part]
        assert name.split(".")[-1] in table, f"{name} missing from default.toml"
    assert all(field_docs().values()), "every field has its one-line documentation"


def test_dump_roundtrip(tmp_path):
    cfg = PipelineConfig().replace(seed=7, grouping={"method": "hough", "ransac": {"iterations": 123},
                                                     "hough": {"bin": 0.02}})
    p = tmp_path / "p.toml"
    p.write_text(dump_toml(cfg))
    assert load_pipeline(p) == cfg


@pytest.mark.parametrize("text, words", [
    ("[grouping]\nbogus = 1\n", "unknown field(s) ['bogus'] in [grouping]"),
    ("[nope]\n", "unknown pipeline section 'nope'"),
    ("[preprocess]\nvoxel = -1\n", "voxel must be > 0"),
    ("[grouping\n", "not valid TOML"),
    ("[grouping.hough]\nbin = 0\n", "[grouping.hough]: HoughConfig.bin must be > 0"),
    ("[grouping]\nhough_bin = 0.02\n", "grouping.hough_bin is now grouping.hough.bin"),
    ("[grouping]\niterations = 100\n", "grouping.iterations is now grouping.ransac.iterations"),
    ("[grouping]\nmethod = \"magic\"\n", "grouping method 'magic' is not available"),
    ("[grouping.ransac]\niterations = 10.5\n", "grouping.ransac.iterations = 10.5: expected an integer"),
    ("[preprocess]\nremove_plane = \"no\"\n", "preprocess.remove_plane = 'no': expected a boolean"),
    ("seed = \"x\"\n", "seed = 'x': expected an integer"),
    ("[verify]\nmin_score = true\n", "verify.min_score = True: expected a number"),
    ("grouping = 3\n", "[grouping] must be a table"),
    ("[matching]\nscreen_eps = -1\n", "MatchingConfig.screen_eps must be >= 0"),
    ("[grouping]\ndistinct = -1\n", "GroupingConfig.distinct must be >= 0"),
    ("[refine]\nplaces = -1\n", "RefineConfig.places must be >= 0"),
    ("[refine]\nretry_places = -1\n", "RefineConfig.retry_places must be >= 0"),
])
def test_bad_presets(tmp_path, text, words):
    p = tmp_path / "bad.toml"
    p.write_text(text)
    with pytest.raises(InputError) as e:
        load_pipeline(p)
    assert "bad.toml" in str(e.value) and words in str(e.value)


def test_unknown_preset_lists_available():
    with pytest.raises(FileNotFoundError, match="available: .*default"):
        load_pipeline("no_such_preset")


@pytest.mark.parametrize("path", sorted(PIPELINES_DIR.glob("*.toml")), ids=lambda p: p.stem)
def test_every_shipped_preset_loads_and_differs_only_where_it_says(path):
    """Each preset in pipelines/ loads; a non-default preset changes at least one field, and every field it
    sets in its file (sub-tables included) ends up in the config."""
    import tomllib

    cfg = load_pipeline(path.stem)

    def check(obj, table, where):
        for k, v in table.items():
            if isinstance(v, dict):
                check(getattr(obj, k), v, f"{where}.{k}")
            else:
                assert getattr(obj, k) == v, (where, k)

    check(cfg, tomllib.loads(path.read_text()), path.stem)
    if path.stem not in ("default", "ransac"):
        assert cfg != PipelineConfig()


def test_presets_layer_left_to_right():
    cfg = load_pipeline("crowded+hough")
    assert cfg.grouping == load_pipeline("hough").grouping
    assert cfg.verify == load_pipeline("crowded").verify and cfg.refine == load_pipeline("crowded").refine
    with pytest.raises(FileNotFoundError, match="nosuch"):
        load_pipeline("crowded+nosuch")


def test_layering_overrides_the_same_field_and_keeps_the_rest(tmp_path):
    """Two layers set the same field: the right one wins; fields only the left one sets survive; a field
    neither sets keeps the code's default."""
    a, b = tmp_path / "a.toml", tmp_path / "b.toml"
    a.write_text("seed = 5\n[verify]\nmin_score = 0.5\nclutter_weight = 2.0\n[refine]\niterations = 12\n")
    b.write_text("seed = 9\n[verify]\nmin_score = 0.6\n")
    cfg = load_pipeline(f"{a}+{b}")
    assert cfg.seed == 9 and cfg.verify.min_score == 0.6
    assert cfg.verify.clutter_weight == 2.0 and cfg.refine.iterations == 12
    assert cfg.verify.depth_tolerance == PipelineConfig().verify.depth_tolerance
    assert load_pipeline(f"{b}+{a}").verify.min_score == 0.5


def test_a_folder_named_like_a_preset_does_not_hide_it(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "crowded").mkdir()  # e.g. a dataset made by `pcdet synth --out crowded`
    assert load_pipeline("crowded+hough") == load_pipeline(PIPELINES_DIR / "crowded.toml").replace(
        grouping=dataclasses.asdict(load_pipeline("hough").grouping))


def test_a_preset_is_looked_up_in_the_package_and_a_path_is_a_path(tmp_path, monkeypatch):
    """Files called ``hough`` and ``hough.toml`` in the current folder change nothing of what ``hough`` means; the
    file is read when named as a path (``./hough.toml``)."""
    monkeypatch.chdir(tmp_path)
    shipped = load_pipeline(PIPELINES_DIR / "hough.toml")
    (tmp_path / "hough").write_text("seed = 77\n")
    (tmp_path / "hough.toml").write_text("seed = 78\n")
    assert load_pipeline("hough") == shipped
    assert load_pipeline("crowded+hough").seed == shipped.seed
    assert load_pipeline("./hough.toml").seed == 78 and load_pipeline("./hough").seed == 77
    assert load_pipeline("crowded+./hough.toml").seed == 78
    with pytest.raises(FileNotFoundError, match="pipeline file not found"):
        load_pipeline("./nosuch.toml")
