"""The FRI messages' schema and its generated module agree, and the enums follow the schema."""

from __future__ import annotations

import re
from pathlib import Path

from google.protobuf.descriptor import FieldDescriptor

from iiwa_ident.fri import messages_pb2

SCHEMA = Path(messages_pb2.__file__).with_name("messages.proto")

_SCALARS = {"double": FieldDescriptor.TYPE_DOUBLE, "uint32": FieldDescriptor.TYPE_UINT32,
            "int32": FieldDescriptor.TYPE_INT32}
_FIELD = re.compile(r"^\s*(repeated\s+)?(\w+)\s+(\w+)\s*=\s*(\d+)\s*(\[[^\]]*\])?\s*;")


def schema_blocks() -> tuple[dict, dict]:
    """Messages {name: {field: (number, type, repeated, required)}} and enums {name: {value: number}} of the text."""
    text = re.sub(r"//[^\n]*", "", SCHEMA.read_text())
    messages, enums = {}, {}
    for kind, name, body in re.findall(r"\b(message|enum)\s+(\w+)\s*\{([^}]*)\}", text):
        if kind == "enum":
            enums[name] = {v: int(n) for v, n in re.findall(r"(\w+)\s*=\s*(\d+)\s*;", body)}
            continue
        fields = {}
        for line in body.split(";"):
            m = _FIELD.match(line + ";")
            if m:
                rep, typ, fname, num, opts = m.groups()
                fields[fname] = (int(num), typ, bool(rep), bool(opts and "LEGACY_REQUIRED" in opts))
        messages[name] = fields
    return messages, enums


def descriptor_blocks() -> tuple[dict, dict]:
    d = messages_pb2.DESCRIPTOR
    messages = {}
    for name, m in d.message_types_by_name.items():
        fields = {}
        for f in m.fields:
            typ = (f.message_type.name if f.message_type else f.enum_type.name if f.enum_type
                   else next(k for k, v in _SCALARS.items() if v == f.type))
            fields[f.name] = (f.number, typ, f.is_repeated, f.is_required)
        messages[name] = fields
    enums = {name: {v.name: v.number for v in e.values} for name, e in d.enum_types_by_name.items()}
    return messages, enums


def test_generated_module_matches_the_schema():
    """An edit of messages.proto without `make proto` (or the reverse) fails here."""
    assert schema_blocks() == descriptor_blocks()


def test_kuka_field_numbers():
    """Facts of KUKA's wire format that the schema must keep (field numbers of what the loop reads)."""
    messages, _ = descriptor_blocks()
    assert messages["MonitoringMessage"]["header"][:1] == (1,)
    assert messages["MonitorData"]["measured_joint_position"][0] == 1
    assert messages["MonitorData"]["measured_torque"][0] == 2
    assert messages["MonitorData"]["external_torque"][0] == 5
    assert messages["MonitorData"]["timestamp"][0] == 15
    assert messages["CommandData"]["joint_torque"][0] == 3
    assert messages["IpoData"]["client_command_mode"][0] == 10
    assert messages["MessageHeader"]["message_identifier"] == (1, "uint32", False, True)


def test_the_written_enums_are_the_schemas():
    """protocol's IntEnums (written out for the type checker) hold the schema's members, prefix dropped."""
    from iiwa_ident import fri

    _, enums = schema_blocks()
    for name, members in enums.items():
        prefix = re.sub(r"(?<!^)(?=[A-Z])", "_", name).upper() + "_"
        written = {m.name: m.value for m in getattr(fri, name)}
        assert written == {k.removeprefix(prefix): v for k, v in members.items()}, name
