"""The settings a user sets per method: the caps on their number, and old configs failing with one line."""

from __future__ import annotations

import pytest
from pydantic import BaseModel

from motionaug.augment.methods.base import TrainingSpec
from motionaug.augment.methods.erd import ErdTrain, ErdTrainConfig
from motionaug.augment.methods.registry import method_class
from motionaug.schemas.errors import MotionDataError


def fields(model: type[BaseModel], skip: tuple[str, ...] = ()) -> list[str]:
    """Every setting of ``model``, nested models' fields counted one by one."""
    out = []
    for name, field in model.model_fields.items():
        kind = field.annotation
        if name in skip:
            continue
        if isinstance(kind, type) and issubclass(kind, BaseModel):
            out += [f"{name}.{inner}" for inner in fields(kind)]
        else:
            out.append(name)
    return out


def test_umsd_holds_at_most_ten_settings_and_fifteen_training_ones() -> None:
    params = method_class("umsd").Params
    assert len(fields(params, skip=("train",))) + 1 <= 10
    assert len(fields(params.model_fields["train"].annotation)) <= 15


def test_style_erd_training_settings_expand_into_the_recipe() -> None:
    train = ErdTrain(steps=7)
    assert train.recipe().model_dump() == ErdTrainConfig(steps=7).model_dump()
    tiny = train.recipe("tiny", 5)
    assert tiny.latent == 8 and tiny.classifier_steps == 2 and tiny.seed == 5 and tiny.steps == 7
    with pytest.raises(MotionDataError, match=r"config base_models\.size: Style-ERD has no network size 'huge'"):
        train.recipe("huge")


@pytest.mark.parametrize(
    ("name", "params", "message"),
    [
        ("erd", {"train": {"latent": 8}}, r"method\.params\.train\.latent: erd: removed; .*base_models\.size"),
        ("erd", {"train": {"w_moments": 0.0}}, r"method\.params\.train\.w_moments: erd: removed; .*lab"),
        ("umsd", {"train": {"seed": 1}}, r"method\.params\.train\.seed: umsd: removed; the run's seed"),
        ("umsd", {"keep": "root"}, r"method\.params\.keep: umsd: removed; "),
        ("umsd", {"guidance_below": 10}, r"method\.params\.guidance_below: umsd: removed; .*lab/README\.md"),
    ],
)
def test_a_removed_setting_is_one_line_saying_what_to_do(name: str, params: dict, message: str) -> None:
    with pytest.raises(MotionDataError, match=message) as err:
        method_class(name).parse_params(params)
    assert "\n" not in str(err.value)


def test_on_the_fly_artefacts_made_before_a_setting_left_still_load() -> None:
    from motionaug.augment.methods.onthefly.params import OnTheFlyParams

    old = {**OnTheFlyParams().model_dump(), "pair_guidance_scale": 2.5, "neutralise_content": True}
    assert OnTheFlyParams.model_validate(old) == OnTheFlyParams()
    with pytest.raises(ValueError, match="neutralise_content was removed"):
        OnTheFlyParams.model_validate({**old, "neutralise_content": False})
    with pytest.raises(MotionDataError, match=r"method\.params\.pair_guidance_scale: onthefly: removed; fixed at 2\.5"):
        method_class("onthefly").parse_params({"pair_guidance_scale": 2.5})


def test_on_the_flys_recipe_only_settings_are_refused_in_a_config_and_kept_in_its_artefacts() -> None:
    from motionaug.augment.methods.onthefly.params import RECIPE_ONLY, OnTheFlyParams, OnTheFlyRecipe, parse_params

    assert not set(RECIPE_ONLY) & set(OnTheFlyParams.model_fields) and len(OnTheFlyParams.model_fields) == 26
    with pytest.raises(MotionDataError, match=r"method\.params\.inpaint_feet: onthefly: removed; fixed at its default"):
        method_class("onthefly").parse_params({"inpaint_feet": True})
    method = method_class("onthefly")({"max_steps": 2})
    assert isinstance(method.params, OnTheFlyRecipe) and method.params.inpaint_feet is False
    recipe = parse_params(max_steps=2, inpaint_feet=True)
    assert recipe.inpaint_feet and method_class("onthefly")(recipe).params is recipe
    with pytest.raises(MotionDataError, match=r"method\.params\.ema_decay: onthefly: 1\.0 outside"):
        parse_params(ema_decay=1.0)


def test_on_the_flys_pre_training_is_its_own_setting_and_its_files_resolve_against_the_config(tmp_path) -> None:
    """``base_models`` keeps what every method means alike; on-the-fly's pre-training is ``method.params.train``."""
    from motionaug.schemas.run_config import BaseModelsConfig, load_run_config
    from motionaug.workflows.pipeline import resolve_method_paths

    assert set(BaseModelsConfig.model_fields) == {"path", "corpus", "pretrain_if_missing", "size"}
    for old, new in (("pretrain", "method.params.train now"), ("from_mdm", "method.params.train.from_mdm now")):
        with pytest.raises(ValueError, match=f"{old} moved: the method's training settings are {new}"):
            BaseModelsConfig.model_validate({old: {} if old == "pretrain" else "x.pt"})
    folder = tmp_path / "configs"
    folder.mkdir()
    path = folder / "run.yaml"
    train = {"from_mdm": "../mdm/model.pt", "clip_weights": "/abs/ViT-B-32.pt", "prior_steps": 10}
    path.write_text(
        "corpus: {path: ../corpus}\noutput: ../run\n"
        "styles: [{name: proud, words: {adjective: proud}, examples: [{source: c1, description: a walk}]}]\n"
        f"method: {{name: onthefly, params: {{train: {train}}}}}\n".replace("'", "")
    )
    config = resolve_method_paths(load_run_config(path), folder)
    assert config.method.params["train"] == {**train, "from_mdm": str((tmp_path / "mdm" / "model.pt").resolve())}
    assert resolve_method_paths(config, tmp_path / "elsewhere") == config  # absolute paths stay as they are
    with pytest.raises(MotionDataError, match=r"config method\.params\.train\.prior_steps"):
        method_class("onthefly")({"train": {"prior_steps": 0}}).check_training(TrainingSpec(size="tiny", seed=0))
