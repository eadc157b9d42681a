"""`rod.material` presets and the new rod keys' validation and serialisation."""

from __future__ import annotations

import math

import pytest
from pydantic import ValidationError

from rodctl.config.rod import MATERIALS, MaterialConfig, RodConfig


def test_solid_wire_section() -> None:
    mat = MaterialConfig(name="spring_steel_wire")
    ei, rho_a = mat.stiffness_and_mass()
    d = 1e-3
    assert ei == pytest.approx(200e9 * math.pi * d**4 / 64)
    assert rho_a == pytest.approx(7850 * math.pi * d**2 / 4)


def test_tube_section_and_overrides() -> None:
    mat = MaterialConfig(name="silicone_tube", diameter=10e-3, wall=2e-3)
    ei, rho_a = mat.stiffness_and_mass()
    d, di = 10e-3, 6e-3
    assert ei == pytest.approx(3e6 * math.pi * (d**4 - di**4) / 64)
    assert rho_a == pytest.approx(1150 * math.pi * (d**2 - di**2) / 4)


def test_power_cable_preset_is_the_default_rod() -> None:
    ei, rho_a = MaterialConfig(name="power_cable").stiffness_and_mass()
    default = RodConfig()
    assert ei == pytest.approx(default.bending_stiffness, rel=1e-3)
    assert rho_a == pytest.approx(default.mass_per_length, rel=1e-3)


@pytest.mark.parametrize("name", sorted(MATERIALS))
def test_every_preset_gives_a_valid_rod(name: str) -> None:
    rod = RodConfig(material={"name": name})
    ei, rho_a = MaterialConfig(name=name).stiffness_and_mass()
    assert rod.bending_stiffness == ei and rod.mass_per_length == rho_a
    # The resolved config (both the material and the computed values) loads again.
    again = RodConfig.model_validate(rod.model_dump())
    assert again == rod


def test_material_conflicts_and_missing_fields_are_refused() -> None:
    with pytest.raises(ValidationError, match="bending_stiffness .* disagrees with material"):
        RodConfig(material={"name": "pvc_tube"}, bending_stiffness=0.1)
    with pytest.raises(ValidationError, match="needs modulus"):
        RodConfig(material={"name": "custom", "diameter": 0.01, "density": 1000})
    with pytest.raises(ValidationError, match="wall"):
        MaterialConfig(name="pvc_tube", wall=5e-3)


def test_gravity_and_table_exclude_each_other() -> None:
    with pytest.raises(ValidationError, match="exclude each other"):
        RodConfig(gravity=(0.0, -9.81), table_friction=0.5)


def test_keys_that_are_off_are_left_out_of_the_dump() -> None:
    # A weightless rod without a table logs the same resolved config as before these keys.
    dump = RodConfig().model_dump()
    assert not {"material", "gravity", "table_friction"} & set(dump)
    on = RodConfig(gravity=(0.0, -9.81), material={"name": "rubber_cord"}).model_dump()
    assert on["gravity"] == (0.0, -9.81) and on["material"]["name"] == "rubber_cord"
    assert RodConfig(table_friction=0.0).model_dump()["table_friction"] == 0.0
