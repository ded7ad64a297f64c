"""A ROS message class from its type name, for the tools that learn a topic's type at run time
(the recorder, `ros2 topic`, `ros2 bag play`).

`message_class('pkg/msg/Name')` imports `pkg.msg` and returns its class `Name`, as ros2cli
resolves a type; the short form 'pkg/Name' (how get_fields_and_field_types names a nested
message) is taken too. Anything else raises MessageTypeError with a one-line reason.
"""

import importlib


class MessageTypeError(ValueError):
    """A type name that names no importable message; the text is a one-line reason."""


def split_message_type(type_name: str) -> tuple[str, str]:
    """(package, Name) of 'pkg/msg/Name' or 'pkg/Name'; MessageTypeError for another form."""
    parts = str(type_name).split('/')
    if len(parts) == 2:
        parts = [parts[0], 'msg', parts[1]]
    if len(parts) != 3 or not all(parts) or parts[1] != 'msg':
        raise MessageTypeError(f"'{type_name}' is not a message type name "
                               '(expected pkg/msg/Name)')
    return parts[0], parts[2]


def message_class(type_name: str) -> type:
    """The Python class of the message type 'pkg/msg/Name' (or 'pkg/Name').

    MessageTypeError when the name has another form, no Python package `pkg` holds a message
    `Name`, or what it holds is not a message class.
    """
    package, name = split_message_type(type_name)
    try:
        cls = getattr(importlib.import_module(f'{package}.msg'), name)
    # TypeError: a package name with a leading '.' reads as a relative import.
    except (ImportError, AttributeError, ValueError, TypeError):
        raise MessageTypeError(f"'{type_name}': no message {name} in a Python package "
                               f'{package}') from None
    if not (isinstance(cls, type) and hasattr(cls, 'get_fields_and_field_types')):
        raise MessageTypeError(f"'{type_name}' is not a message")
    return cls
