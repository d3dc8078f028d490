"""Plant files: the shipped default, validation with errors naming the key, round trips."""

from __future__ import annotations

import math

import pytest

from iiwa_ident.errors import PlantError
from iiwa_ident.sim import default_plant, load_plant, plant_from_dict, save_plant


class TestDefaultPlant:
    def test_is_table1_with_ripple(self):
        p = default_plant()
        assert p.dynamics == {"Jc": 1.03, "bc": 55.0, "K": 18500.0, "Jl": 5.6, "Td": 0.005}
        assert p.internal["KI"] == 25.0
        assert p.sensors["encoder_tick_rad"] == 5.989e-8
        ripple = p.effect("transmission_ripple")
        assert ripple.values["period_rad"] == 0.01963
        assert p.limits.torque_nm == 320.0 and p.limits.position_rad == pytest.approx(math.radians(170))


class TestValidation:
    @pytest.mark.parametrize("data, key", [
        ({"dynamics": {"Jc": -1.0}}, "dynamics.Jc"),
        ({"dynamics": {"Jl": math.nan}}, "dynamics.Jl"),
        ({"dynamics": {"K": "stiff"}}, "dynamics.K"),
        ({"dynamics": {"Kx": 1.0}}, "dynamics.Kx"),
        ({"internal": {"KI": math.inf}}, "internal.KI"),
        ({"sensors": {"ft_sensor": 1}}, "sensors.ft_sensor"),
        ({"robot": {"joint": 9}}, "robot.joint"),
        ({"robot": {"model": "iiwa99"}}, "robot.model"),
        ({"colour": "red"}, "colour"),
        ({"format_version": 2}, "format_version"),
        ({"effects": {"warp_drive": {}}}, "effects.warp_drive"),
        ({"effects": {"link_friction": {"coulomb_nm": -1.0}}}, "effects.link_friction.coulomb_nm"),
        ({"effects": {"link_friction": {"stiction": 1.0}}}, "effects.link_friction.stiction"),
        ({"effects": {"transmission_ripple": {"period_rad": 0.02}}}, "effects.transmission_ripple"),
        ({"effects": {"transmission_ripple": {"harmonics": [[1e-5]]}}}, "effects.transmission_ripple.harmonics[0]"),
        ({"effects": {"transmission_ripple": {"lut": [0.0, math.nan, 0.0, 0.0]}}}, "effects.transmission_ripple.lut[1]"),
    ])
    def test_error_names_key(self, data, key):
        with pytest.raises(PlantError) as err:
            plant_from_dict(data, where="p.toml: ")
        msg = str(err.value)
        assert msg.startswith(f"p.toml: {key}")
        assert "\n" not in msg

    def test_disabled_effect_is_off(self):
        p = plant_from_dict({"effects": {"link_friction": {"enabled": False, "coulomb_nm": 3.0}}})
        assert p.effects == []

    def test_file_errors(self, tmp_path):
        with pytest.raises(PlantError, match="no such file"):
            load_plant(tmp_path / "missing.toml")
        bad = tmp_path / "bad.toml"
        bad.write_text("[dynamics\nJc = 1")
        with pytest.raises(PlantError, match=f"{bad}: not valid TOML"):
            load_plant(bad)


class TestRoundTrip:
    def test_save_and_load(self, tmp_path):
        p = default_plant()
        p.dynamics["K"] = 12345.0
        path = save_plant(p, tmp_path / "plant.toml")
        q = load_plant(path)
        assert q.to_dict() == p.to_dict()
