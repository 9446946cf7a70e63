"""Run config: YAML/JSON loading, overrides, path resolution and field-named validation (no Ray)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from pydantic import ValidationError

from motionaug.schemas.errors import MotionDataError
from motionaug.schemas.run_config import RunConfig, apply_overrides, load_run_config, parse_override

STYLE = {
    "name": "proud",
    "words": {"adjective": "proud", "adverb": "proudly"},
    "examples": [{"source": "examples/proud.npy", "description": "a person walks proudly"}],
}


def base() -> dict:
    return {"corpus": {"path": "corpus"}, "styles": [dict(STYLE)], "output": "runs/x"}


def test_yaml_and_json_give_the_same_config_with_paths_resolved(tmp_path: Path) -> None:
    import yaml

    (tmp_path / "a.yaml").write_text(yaml.safe_dump(base()))
    (tmp_path / "a.json").write_text(json.dumps(base()))
    a, b = load_run_config(tmp_path / "a.yaml"), load_run_config(tmp_path / "a.json")
    assert a == b
    assert a.corpus.path == (tmp_path / "corpus").resolve() and a.output == (tmp_path / "runs/x").resolve()
    assert a.styles[0].examples[0].source == str((tmp_path / "examples/proud.npy").resolve())
    assert a.compute.batch_size == 32 and a.fan_out.per_clip == "all" and a.method.name == "stats"


def test_overrides_are_typed_and_nested() -> None:
    assert parse_override("compute.batch_size=8") == (["compute", "batch_size"], 8)
    assert parse_override("compute.address=null") == (["compute", "address"], None)
    data = apply_overrides(base(), ["compute.unit_size=16", "method.params.strength=0.5", "fan_out.per_clip=1"])
    config = RunConfig.model_validate(data)
    assert config.compute.unit_size == 16 and config.method.params == {"strength": 0.5} and config.fan_out.per_clip == 1
    with pytest.raises(ValueError, match="key.sub=value"):
        parse_override("compute.batch_size")


@pytest.mark.parametrize(
    ("override", "field"),
    [
        ("compute.batch_size=-1", "compute.batch_size"),
        ("compute.unit_size=0", "compute.unit_size"),
        ("compute.colour=1", "compute.colour"),
        ("fan_out.per_clip=3", "fan_out.per_clip"),
        ("corpus.filters.caption_regex=(", "corpus.filters.caption_regex"),
        ("corpus.format=csv", "corpus.format"),
        ("base_models.size=huge", "base_models.size"),
        ("version=2", "version"),
    ],
)
def test_bad_values_name_their_field(override: str, field: str) -> None:
    with pytest.raises(ValidationError) as info:
        RunConfig.model_validate(apply_overrides(base(), [override]))
    err = info.value.errors()[0]
    where = ".".join(str(p) for p in err["loc"])
    assert where.startswith(field) or field.split(".")[0] == "fan_out" and "per_clip" in str(info.value)


def test_duplicate_style_names_and_empty_styles_are_refused() -> None:
    with pytest.raises(ValidationError, match="unique"):
        RunConfig.model_validate({**base(), "styles": [dict(STYLE), dict(STYLE)]})
    with pytest.raises(ValidationError, match="styles"):
        RunConfig.model_validate({**base(), "styles": []})


def test_top_level_must_be_a_mapping(tmp_path: Path) -> None:
    (tmp_path / "bad.yaml").write_text("- 1\n- 2\n")
    with pytest.raises(ValueError, match="mapping"):
        load_run_config(tmp_path / "bad.yaml")


def test_every_shipped_config_loads_and_its_method_params_validate() -> None:
    """Also what preflight checks of each example without its corpus: the description names the style."""
    from motionaug.augment.corpus.style_examples import describes_style
    from motionaug.augment.methods.hooks import output_shapers
    from motionaug.augment.methods.registry import validate_method_params
    from motionaug.augment.methods.shapers import STYLE_ERD_CHAIN

    configs = sorted((Path(__file__).parents[1] / "configs").glob("*.yaml"))
    assert {p.name for p in configs} >= {
        "onthefly-humanml3d.yaml",
        "onthefly-lora-synthetic.yaml",
        "stats-synthetic.yaml",
    }
    for path in configs:
        config = load_run_config(path)
        params = validate_method_params(config.method.name, config.method.params)
        output_shapers.create_all(config.method.shapers)  # every shaper a config names is the product's own
        for style in config.styles:
            for example in style.examples:
                assert describes_style(example.description, style.words), (path.name, style.name)
        if path.name == "onthefly-lora-synthetic.yaml":  # the recipe bench/RESULTS.md measured
            assert params["lora_rank"] == 4 and "poseFinal" in params["lora_targets"]
        if config.method.name == "erd":  # the chain RESULTS section 0 measured with Style-ERD
            assert config.method.shapers == list(STYLE_ERD_CHAIN), path.name


def test_a_yaml_syntax_error_names_file_line_and_column(tmp_path: Path) -> None:
    path = tmp_path / "broken.yaml"
    path.write_text("corpus:\n  path: runs/x\nstyles: [proud\n")
    with pytest.raises(MotionDataError, match=r"broken\.yaml:\d+:\d+: not valid YAML"):
        load_run_config(path)


def test_motion_data_error_pickles_with_its_source_and_reason() -> None:
    """Ray carries a task's exception back by pickling it; the one-line message must survive."""
    import pickle

    err = pickle.loads(pickle.dumps(MotionDataError("clip 000001", "NaN at frame 3")))
    assert (err.source, err.reason, str(err)) == ("clip 000001", "NaN at frame 3", "clip 000001: NaN at frame 3")
