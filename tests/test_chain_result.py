"""The chain's typed step (hil.ident.result.ChainStep): its JSON is the documented ``chain[]`` of
``hil diagnose --json`` (the reference the independent checks read), with the optional keys only
where the step has them; the internal fits and config never reach it."""
import json

import pytest

from hil.commands.diagnose import JSON_KEYS
from hil.ident.result import ChainStep
from hil.io.jsonout import dumps

DOCUMENTED = {k.split(".", 1)[1].split(".")[0] for k in JSON_KEYS if k.startswith("chain[].")}
OPTIONAL = {"swapped", "beyond_tolerance", "dropped", "nights_plant", "estimation_error", "held_out"}


def _step(**kw):
    base = dict(step=1, effect="backlash", effects=["backlash"], params={"backlash": {"gap": 2e-5}},
                error_before={"x_motor": 1e-5}, error_after={"x_motor": 1e-7}, gap_closed={"x_motor": 0.99},
                score=120.0, evidence="at reversals", refitted_together=False, stderr={"backlash.gap": 1e-7},
                confounded=[], aliases={}, rival=None, recording_artefacts=[], fits=["fit"], config={"cfg": 1})
    return ChainStep(**dict(base, **kw))


def test_the_json_keys_are_the_documented_ones():
    bare = _step()
    assert set(bare.keys()) == DOCUMENTED - OPTIONAL
    full = _step(swapped="current_loop", beyond_tolerance={"verdict": "parameter:plant.m3", "effect": "parameter:plant.k1",
                                                           "key": "plant.k1", "change": -0.18, "tolerance": 0.05,
                                                           "params": {"plant.k1": -0.18}},
                 dropped=[{"effect": "current_loop", "params": {}, "score": 3.0}],
                 nights_plant={"effects": ["backlash"], "tolerance": 0.05, "params": {}, "stderr": {},
                               "error_on_config_plant": {"x_motor": 1e-6}},
                 estimation_error={"x_motor": 1e-7}, held_out={"earned": True})
    assert set(full.keys()) == DOCUMENTED
    out = json.loads(dumps({"chain": [full.as_json()]}))["chain"][0]
    assert list(out) == full.keys() and out["swapped"] == "current_loop" and out["held_out"]["earned"]
    # the internal parts stay on the object
    assert not {"fits", "joint", "config", "runner_up"} & set(out)


def test_read_as_a_mapping_where_it_stands_beside_the_refused_step():
    s = _step(held_out={"earned": True}, estimation_error={"x_motor": 1e-7})
    assert s["effects"] == ["backlash"] and "held_out" in s and "dropped" not in s
    assert s.get("dropped", []) == [] and s.get("swapped") is None
    with pytest.raises(KeyError):
        s["config"]          # internal: an attribute, not a key of the JSON
    assert s.config == {"cfg": 1}
