"""The design file: round trip and validation of every key."""

from __future__ import annotations

import copy
import hashlib
import math
import tomllib

import numpy as np
import pytest

from iiwa_ident._toml import dumps_toml
from iiwa_ident.design import FilterSettings
from iiwa_ident.design._additive import design_controller
from iiwa_ident.design._design_file import (
    DESIGN_FORMAT,
    DesignFileError,
    design_from_dict,
    design_to_dict,
    make_record,
    read_design,
    write_design,
)
from iiwa_ident.design._margins import HumanArm, OuterLoopMargins
from iiwa_ident.ident import write_model
from iiwa_ident.model import JointParameters, RippleTable, table1_model

TABLE1 = JointParameters(1.03, 55.0, 18500.0, 5.6, 0.005)
# Margins are not recomputed on reading; fixed numbers keep these tests fast.
MARGINS = OuterLoopMargins(builtin=7.78, additive=23.0, arm=HumanArm(300.0, 40.0, 0.0), kappa_limit=100.0)


@pytest.fixture(scope="module")
def record_dict():
    model = table1_model()
    model.ripple = RippleTable(0.01963, np.sin(np.linspace(0, 2 * np.pi, 16, endpoint=False)) * 5e-5)
    rec = make_record(design_controller(TABLE1), MARGINS, model, filter=FilterSettings(4.0, 0.3))
    return design_to_dict(rec)


def write_dict(path, data):
    path.write_text(dumps_toml(data))
    return path


class TestWriteDesign:
    def test_round_trip(self, tmp_path):
        model = table1_model()
        model_path = tmp_path / "model.toml"
        write_model(model_path, model)
        design = design_controller(TABLE1)
        margins = OuterLoopMargins(7.5, math.inf, HumanArm(250.0, 30.0, 0.2), 50.0)
        rec = make_record(design, margins, model, model_path, FilterSettings(5.0, 0.2), description="test")
        path = write_design(tmp_path / "design.toml", rec)
        back = read_design(path)
        d, b = design, back.design
        for name in ("A", "B", "C", "K_fsf", "L", "Ad", "Bd", "Kd", "Ld", "poles", "observer_poles",
                     "builtin_poles", "additive_poles", "additive_poles_discrete"):
            np.testing.assert_array_equal(getattr(b, name), getattr(d, name), err_msg=name)
        for name in ("Kr", "Kr_c", "Kr_d", "c1", "c2", "sample_time_s", "prefilter_hz", "prefilter_zeta"):
            assert getattr(b, name) == getattr(d, name), name
        for i in range(4):
            np.testing.assert_array_equal(b.ffd[i], d.ffd[i])
            np.testing.assert_array_equal(b.ff[i], d.ff[i])
        assert b.params == d.params and b.feedforward == "reference"
        assert back.margins == margins
        assert back.KI == 25.0 and back.filter == FilterSettings(5.0, 0.2)
        assert back.model_file == str(model_path)
        assert back.model_sha256 == hashlib.sha256(model_path.read_bytes()).hexdigest()
        assert back.description == "test"

    def test_read_design_runs_identically(self, tmp_path):
        design = design_controller(TABLE1, feedforward="paper")
        path = write_design(tmp_path / "d.toml", make_record(design, MARGINS, table1_model()))
        c1, c2 = design.controller(), read_design(path).design.controller()
        rng = np.random.default_rng(0)
        for r, y in rng.normal(size=(50, 2)):
            assert c1.step(r, y) == c2.step(r, y)

    def test_ripple_and_no_prefilter(self, tmp_path, record_dict):
        back = design_from_dict(copy.deepcopy(record_dict))
        assert back.ripple is not None and len(back.ripple.lut) == 16
        assert back.filter.beta == 4.0 and back.filter.v_min_rad_s == 0.3
        design = design_controller(TABLE1, feedforward="none")
        path = write_design(tmp_path / "n.toml", make_record(design, MARGINS, table1_model()))
        assert "[prefilter]" not in path.read_text()
        assert read_design(path).design.ffd is None

    def test_atomic_and_validated(self, tmp_path):
        out = tmp_path / "sub" / "d.toml"
        write_design(out, make_record(design_controller(TABLE1), MARGINS, table1_model()))
        assert out.exists() and not list(out.parent.glob(".*.tmp"))
        assert tomllib.loads(out.read_text())["format"] == DESIGN_FORMAT


def _set(data, key, value):
    parts = key.split(".")
    node = data
    for p in parts[:-1]:
        node = node[p]
    if value is _DELETE:
        del node[parts[-1]]
    else:
        node[parts[-1]] = value


_DELETE = object()


class TestDesignFromDict:
    @pytest.mark.parametrize("key, value, message", [
        ("format", "iiwa-ident-model", "format: expected 'iiwa-ident-design'"),
        ("format_version", 1, "format_version: unsupported version 1 (this tool reads 2)"),
        ("extra", 1, "extra: unknown key"),
        ("gains.Kx", 1.0, "gains.Kx: unknown key"),
        ("sample_time_s", -0.001, "sample_time_s: must be positive"),
        ("sample_time_s", "1ms", "sample_time_s: expected a number"),
        ("feedforward", "both", "feedforward: expected one of"),
        ("filter", _DELETE, "filter: missing"),
        ("filter.beta", _DELETE, "filter.beta: missing"),
        ("filter.v_min_rad_s", 0.0, "filter.v_min_rad_s: must be positive"),
        ("torque_observer.KI", 30.0, "torque_observer.KI: differs from model.parameters.KI"),
        # one period for the spatial filter and the lookup table: model.ripple.period_rad
        ("filter.period_rad", 0.0197, "filter.period_rad: unknown key"),
        ("model.parameters.Jc.value", -1.0, "model.parameters.Jc.value: must be positive"),
        ("model.parameters.K.unit", "N/m", "model.parameters.K.unit: expected 'Nm/rad'"),
        ("model.parameters.Td", 0.005, "model.parameters.Td: expected a table"),
        ("model.parameters.bc", _DELETE, "model.parameters.bc: missing"),
        ("model.sha256", "xyz", "model.sha256: expected 64 lower-case hex digits"),
        ("model.ripple.lut", [1.0, 2.0], "model.ripple.lut: expected a list of at least 4"),
        ("poles.controller", [[-180.0, 30.0], [-180.0, -30.0], [-500.0, 1.0]], "poles.controller: expected 4"),
        ("poles.controller", [[-180.0, 30.0], [-180.0, -30.0], [-500.0, 1.0], [500.0, -1.0]],
         "poles.controller: poles: 500-1j is not stable"),
        ("poles.observer", [[-620.0, 5.0], [-630.0, 0.0], [-1000.0, 0.0], [-1010.0, 0.0]],
         "poles.observer: observer poles: -620+5j has no conjugate partner"),
        ("poles.additive", [[1.0, 0.0]], "poles.additive: expected 8 [re, im] pairs"),
        ("continuous.A", [[1.0, 2.0], [3.0, 4.0]], "continuous.A: expected shape 4x4, got 2x2"),
        ("continuous.B", [1.0, "x", 3.0, 4.0], "continuous.B: expected an array of numbers"),
        ("continuous.C", [1.0, 0.0, 0.0, 0.0], "continuous.C: expected [0, 0, 0, 1]"),
        ("discrete.Bd", [1.0, 2.0, 3.0, math.nan], "discrete.Bd: entries must be finite"),
        ("gains.Kd", [0.0, 0.0, 0.0, 0.0], "gains.Kd: does not place the poles"),
        ("gains.L", [1.0, 1.0, 1.0, 1.0], "gains.L: does not place the poles"),
        ("gains.Kr", math.inf, "gains.Kr: must be finite"),
        ("prefilter", _DELETE, 'prefilter: missing (required with feedforward = "reference")'),
        ("prefilter.Ad", [[2.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]], "prefilter.Ad: is not stable"),
        ("prefilter.Bd", [1.0, 2.0], "prefilter.Bd: expected shape 3"),
        ("outer_loop.kappa_max_additive", -1.0, "outer_loop.kappa_max_additive: must not be negative"),
        ("outer_loop.arm_stiffness", 0.0, "outer_loop.arm_stiffness: must be positive"),
        ("outer_loop.kappa_limit", _DELETE, "outer_loop.kappa_limit: missing"),
    ])
    def test_bad_file_names_file_and_key(self, tmp_path, record_dict, key, value, message):
        data = copy.deepcopy(record_dict)
        _set(data, key, value)
        path = write_dict(tmp_path / "bad.toml", data)
        with pytest.raises(DesignFileError) as err:
            read_design(path)
        assert str(err.value).startswith(f"{path}: ")
        assert message in str(err.value)

    def test_prefilter_with_none_mode(self, tmp_path, record_dict):
        data = copy.deepcopy(record_dict)
        data["feedforward"] = "none"
        path = write_dict(tmp_path / "bad.toml", data)
        with pytest.raises(DesignFileError, match='prefilter: present although feedforward = "none"'):
            read_design(path)

    def test_infinite_kappa_allowed(self, record_dict):
        data = copy.deepcopy(record_dict)
        data["outer_loop"]["kappa_max_additive"] = math.inf
        assert design_from_dict(data).margins.additive == math.inf


class TestReadDesign:
    def test_missing_file(self, tmp_path):
        with pytest.raises(DesignFileError, match="no such file"):
            read_design(tmp_path / "none.toml")

    def test_not_toml(self, tmp_path):
        path = tmp_path / "x.toml"
        path.write_text("format = \n")
        with pytest.raises(DesignFileError, match=f"{path}: not valid TOML"):
            read_design(path)
