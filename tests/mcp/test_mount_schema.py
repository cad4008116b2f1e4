"""``host.mounts``' pure parts: ``--mount-mcp`` arguments, JSON Schema -> typed parameters, names."""

from __future__ import annotations

import inspect
import re
from typing import Annotated, Literal, Optional, Union

import pytest
from annotated_types import Interval, MaxLen

from host.mounts.schema import Unsupported, attribute_names, function_names, tool_interface
from host.mounts.spec import MountSpec, MountSpecError, parse_mount_arg
from host.shell.mapper import BadValue, convert_value


def one(prop: dict, required: bool = True):
    """The single parameter of a tool whose only property is ``prop``."""
    iface = tool_interface({"type": "object", "properties": {"p": prop}, "required": ["p"] if required else []}, "")
    (param,) = iface.params
    return param


@pytest.mark.parametrize("prop, annotation", [
    ({"type": "string"}, str),
    ({"type": "string", "maxLength": 5}, Annotated[str, MaxLen(5)]),
    ({"type": "integer"}, int),
    ({"type": "number", "minimum": 0, "maximum": 2.5}, Annotated[float, Interval(ge=0, le=2.5)]),
    ({"type": "number", "exclusiveMinimum": 0}, Annotated[float, Interval(gt=0)]),
    ({"type": "integer", "exclusiveMinimum": 0, "exclusiveMaximum": 10}, Annotated[int, Interval(ge=1, le=9)]),
    ({"type": "integer", "minimum": 0, "exclusiveMinimum": True}, Annotated[int, Interval(ge=1)]),  # draft 4
    ({"type": "number", "maximum": 1, "exclusiveMaximum": True}, Annotated[float, Interval(lt=1)]),
    ({"type": "boolean"}, bool),
    ({"enum": ["a", "b"]}, Literal["a", "b"]),
    ({"enum": [1, 2, None]}, Optional[Literal[1, 2]]),
    ({"const": "x"}, Literal["x"]),
    ({"type": ["string", "null"]}, Optional[str]),
    ({"anyOf": [{"type": "integer"}, {"type": "null"}]}, Optional[int]),
    ({"oneOf": [{"type": "integer"}, {"type": "string"}]}, Union[int, str]),
    ({"type": "array", "items": {"type": "integer"}}, list[int]),
    ({"type": "array", "items": {"enum": ["x", "y"]}, "maxItems": 2}, Annotated[list[Literal["x", "y"]], MaxLen(2)]),
    ({}, str),
    ({"description": "anything"}, str),
    ({"allOf": [{"type": "integer", "minimum": 1}]}, Annotated[int, Interval(ge=1)]),
])
def test_json_schema_constructs_become_shell_types(prop: dict, annotation: object) -> None:
    assert one(prop).annotation == annotation


def test_refs_defaults_descriptions_and_order() -> None:
    schema = {
        "type": "object",
        "$defs": {"Unit": {"enum": ["C", "F"], "type": "string"}},
        "properties": {
            "unit": {"$ref": "#/$defs/Unit", "default": "C", "description": "The unit"},
            "city": {"type": "string", "description": "City", "pattern": "^[A-Z]", "title": "City"},
            "note": {"anyOf": [{"type": "string"}, {"type": "null"}]},
        },
        "required": ["city"],
    }
    iface = tool_interface(schema, "Get it.")
    assert [p.name for p in iface.params] == ["city", "unit", "note"]  # required first
    city, unit, note = iface.params
    assert city.default is inspect.Parameter.empty and unit.default == "C" and note.default is None
    assert unit.annotation == Literal["C", "F"]
    assert iface.doc.startswith("Get it.\nArgs:\n")
    assert "city: City; pattern '^[A-Z]' (checked by the server)" in iface.doc and "unit: The unit" in iface.doc


@pytest.mark.parametrize("prop, construct", [
    ({"type": "object", "properties": {"x": {"type": "number"}}}, "is an object"),
    ({"type": "array", "items": {"type": "object"}}, "is an array of objects"),
    ({"type": "array", "items": {"type": "array", "items": {"type": "integer"}}}, "is an array of arrays"),
    ({"type": "array", "prefixItems": [{"type": "integer"}]}, "a tuple array"),
    ({"anyOf": [{"type": "integer"}, {"type": "object"}]}, "'anyOf' with an object"),
    ({"allOf": [{"type": "integer"}, {"minimum": 1}]}, "'allOf' of 2 schemas"),
    ({"not": {"type": "string"}}, "'not'"),
    ({"$ref": "https://example.com/schema.json"}, "a $ref to 'https://example.com/schema.json' outside"),
    ({"$ref": "#/$defs/Missing"}, "which the schema does not define"),
    ({"$ref": "#/$defs/Loop"}, "$ref chains deeper than"),
    ({"enum": [{"a": 1}]}, "an enum with non-scalar values"),
    ({"type": "null"}, "can only be null"),
])
def test_unsupported_constructs_skip_a_tool_or_drop_an_optional_parameter(prop: dict, construct: str) -> None:
    defs = {"Loop": {"$ref": "#/$defs/Loop"}}
    with pytest.raises(Unsupported, match=f"parameter 'p' (is )?.*{re.escape(construct)}"):
        tool_interface({"type": "object", "$defs": defs, "properties": {"p": prop}, "required": ["p"]}, "")
    iface = tool_interface({"type": "object", "$defs": defs, "properties": {"p": prop, "q": {"type": "string"}}}, "")
    assert [p.name for p in iface.params] == ["q"]
    (note,) = iface.notes
    assert note.startswith("optional parameter 'p' left out: it is") and construct.removeprefix("is ") in note


def test_a_root_schema_that_is_not_an_object_property_list_is_unsupported() -> None:
    with pytest.raises(Unsupported, match="'oneOf' at the top"):
        tool_interface({"type": "object", "oneOf": [{"required": ["a"]}, {"required": ["b"]}]}, "")
    with pytest.raises(Unsupported, match="an input schema of type 'array'"):
        tool_interface({"type": "array"}, "")
    assert tool_interface({"type": "object"}, None).params == ()


def test_converted_types_use_the_mappers_own_checks() -> None:
    ann = one({"type": "number", "exclusiveMinimum": 0, "maximum": 10}).annotation
    assert convert_value("0.5", ann) == 0.5
    with pytest.raises(BadValue, match="must be greater than 0"):
        convert_value("0", ann)
    with pytest.raises(BadValue, match=r"out of range \[-inf, 10\]"):
        convert_value("11", ann)
    arr = one({"type": "array", "items": {"type": "integer", "minimum": 1}, "maxItems": 2}).annotation
    assert convert_value("[1, 2]", arr) == [1, 2]
    with pytest.raises(BadValue, match=r"\[1\]=.*out of range"):
        convert_value("[1, 0]", arr)
    with pytest.raises(BadValue, match="3 items; at most 2"):
        convert_value("[1, 1, 1]", arr)
    assert convert_value("null", one({"type": ["integer", "null"]}).annotation) is None


def test_names_are_mapped_to_unique_xml_names() -> None:
    names = function_names("weather", ["get forecast!", "get_forecast", "a:b", "ünï-code.v2", "..", "1st"])
    assert names["get_forecast"] == ("weather.get_forecast", None)
    assert names["get forecast!"][0] == "weather.get_forecast_2" and "not an XML name" in (names["get forecast!"][1] or "")
    assert names["a:b"][0] == "weather.a_b"
    assert names["ünï-code.v2"] == ("weather.ünï-code.v2", None)
    assert names[".."][0] == "weather.tool"
    assert names["1st"] == ("weather.1st", None)  # valid after "weather."
    attrs = attribute_names(["sync", "city name", "city_name", "2d", "ok"])
    assert attrs["sync"][0] == "sync_" and attrs["ok"] == ("ok", None)
    assert attrs["city_name"] == ("city_name", None) and attrs["city name"][0] == "city_name_2"
    assert attrs["2d"][0] == "_2d"


def test_mount_arguments_parse_and_round_trip() -> None:
    spec = parse_mount_arg('weather=python "tests/support/weather server.py" --flood')
    assert spec == MountSpec("weather", command=("python", "tests/support/weather server.py", "--flood"))
    assert parse_mount_arg(str(spec)) == spec and spec.kind == "stdio"
    url = parse_mount_arg("arm=http://127.0.0.1:8000/mcp")
    assert url.url == "http://127.0.0.1:8000/mcp" and url.kind == "http" and parse_mount_arg(str(url)) == url
    for bad, why in [("weather", "expected NAME=COMMAND"), ("=python x", "NAME must be"), ("wait=python x", "reserved"),
                     ("main=python x", "reserved"), ("a.b=python x", "NAME must be"), ("w=", "expected"),
                     ("w=ftp://host/x", "not an http"), ("w=http:///mcp", "not an http"),
                     ("w=http://h/mcp extra", "takes no arguments"), ("w=python 'unclosed", "cannot split")]:
        with pytest.raises(MountSpecError, match=why):
            parse_mount_arg(bad)
    with pytest.raises(MountSpecError, match="exactly one"):
        MountSpec("w")


def test_a_bad_mount_argument_is_an_argparse_usage_error_with_its_message(capsys: pytest.CaptureFixture[str]) -> None:
    import argparse

    parser = argparse.ArgumentParser(prog="ghostshell run")
    parser.add_argument("--mount-mcp", type=parse_mount_arg, action="append", default=[])
    assert parser.parse_args(["--mount-mcp", "w=python s.py"]).mount_mcp == [MountSpec("w", command=("python", "s.py"))]
    with pytest.raises(SystemExit) as exited:
        parser.parse_args(["--mount-mcp", "wait=python s.py"])
    assert exited.value.code == 2
    assert "argument --mount-mcp: --mount-mcp wait: 'wait' is reserved by the shell" in capsys.readouterr().err
