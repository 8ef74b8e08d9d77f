"""Loaded (via PYTHONPATH) only by the Python processes of the interface build.

rosidl_parser 4.6.x (Jazzy) finds the module that holds a constant by *structural* equality of
parse trees, so when an action's result and feedback both declare the same constant with the
same value (Nav2's DockRobot: ``uint16 NONE=0`` in both), the feedback's constant is filed
under the result, and the generated C header declares the result's enumerator twice. Looking
the node up by identity files every constant under its own message. Type hashes are not
affected (constants are not part of a type description).
"""

try:
    import rosidl_parser.parser as _parser
    from lark import Tree

    def _find_path(node, target):  # type: ignore[no-untyped-def]
        if node is target:
            return [node]
        for child in node.children:
            if isinstance(child, Tree):
                tail = _find_path(child, target)
                if tail is not None:
                    return [node] + tail
        return None

    _parser._find_path = _find_path
except Exception:  # noqa: BLE001 - the build must not depend on this module importing
    pass
