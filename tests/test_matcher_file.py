"""The matcher file (training's output, export's input): round trip and field-by-field checks."""

from __future__ import annotations

import pytest
import torch

from xvmatch.models.matcher_file import MatcherFileError, load_matcher, save_matcher


def test_round_trip_keeps_every_part(tiny_models):
    full = load_matcher(tiny_models["full"])
    assert full.gamma == 0.5 and full.meta == {"k": 1}
    assert full.matcher.cues == ("app", "ray", "cheir") and not full.matcher.training
    assert full.appearance is not None and full.crop_context == pytest.approx(0.1)
    boxes = load_matcher(tiny_models["boxes"])
    assert boxes.matcher.cues == () and boxes.appearance is None and boxes.gamma == 0.6
    assert boxes.feature_config == full.feature_config


def _broken(tmp_path, source, name: str, **changes) -> str:
    record = torch.load(source, weights_only=True)
    for key, value in changes.items():
        if value is KeyError:
            record.pop(key)
        else:
            record[key] = value
    path = tmp_path / f"{name}.pt"
    torch.save(record, path)
    return str(path)


def test_every_field_is_checked_and_errors_name_the_file(tmp_path, tiny_models):
    source = tiny_models["boxes"]
    record = torch.load(source, weights_only=True)
    state = dict(record["state_dict"])
    name = next(k for k, v in state.items() if v.is_floating_point())
    nan_state = {**state, name: torch.full_like(state[name], float("nan"))}
    cases = {
        "missing": (None, "no such matcher file"),
        "format_version": ({"format_version": 9}, "format version 9"),
        "feature_version": ({"feature_version": 1}, "feature version 1"),
        "old_geometry": ({"format": "xvmatch-geometry-model"}, "depend on the image resolution"),
        "other": ({"format": "something"}, "not a matcher file"),
        "meta_int": ({"meta": 3}, "field 'meta' must be dict, got int"),
        "gamma_text": ({"gamma": "0.5"}, "field 'gamma' must be int or float, got str"),
        "gamma_bool": ({"gamma": True}, "field 'gamma' must be int or float, got bool"),
        "gamma_range": ({"gamma": 2.0}, r"gamma' must be in \(0, 1\]"),
        "no_state": ({"state_dict": KeyError}, "lacks the field 'state_dict'"),
        "nan": ({"state_dict": nan_state}, f"weight '{name}' holds NaN"),
        "config": ({"geometry_config": {**record["geometry_config"], "width": 32}},
                   "does not fit its configuration"),
        "cues_no_app": ({"matcher_config": {"cues": ["app"], "hidden": 32}},
                        "does not fit|appearance network must be present"),
        "no_appearance_field": ({"appearance": KeyError}, "lacks the field 'appearance'"),
    }
    for case, (changes, message) in cases.items():
        path = (str(tmp_path / "nope.pt") if changes is None
                else _broken(tmp_path, source, case, **changes))
        with pytest.raises(MatcherFileError, match=message) as info:
            load_matcher(path)
        assert str(info.value).startswith(path), case
    text = tmp_path / "text.pt"
    text.write_text("not a model")
    with pytest.raises(MatcherFileError, match=r"text\.pt: not a matcher file"):
        load_matcher(text)
    torch.save([1, 2], tmp_path / "list.pt")
    with pytest.raises(MatcherFileError, match="expected a dict record"):
        load_matcher(tmp_path / "list.pt")


def test_save_refuses_what_it_could_not_load(tmp_path, tiny_models):
    loaded = load_matcher(tiny_models["full"])
    with pytest.raises(ValueError, match="folder"):
        save_matcher(tmp_path / "no" / "m.pt", loaded.matcher, loaded.feature_config,
                     appearance=loaded.appearance)
    with pytest.raises(ValueError, match="appearance network is needed"):
        save_matcher(tmp_path / "m.pt", loaded.matcher, loaded.feature_config)
    with pytest.raises(ValueError, match="gamma"):
        save_matcher(tmp_path / "m.pt", loaded.matcher, loaded.feature_config, gamma=0.0,
                     appearance=loaded.appearance)
    with pytest.raises(TypeError):
        save_matcher(tmp_path / "m.pt", loaded.matcher, loaded.feature_config,
                     meta={"x": object()}, appearance=loaded.appearance)
