"""ROS 2 names the package writes itself (topics of a bag it records offline), checked by ROS's
own rules so that a bag never holds a name no ROS node could have published.

:func:`check_namespace` follows rmw's ``rmw_validate_namespace`` (ros2/rmw
``validate_namespace.c``; the rules of design.ros2.org "Topic and Service name mapping"), after
the one normalization rcl applies to a node's namespace (a relative ``truck1`` is made absolute,
``/truck1``):

* absolute: starts with ``/``; ``/`` alone is the root namespace (returned as ``''``);
* tokens separated by single ``/`` (no ``//``), no trailing ``/``;
* a token is ``[A-Za-z_][A-Za-z0-9_]*`` (letters, digits, underscores; not starting with a
  digit);
* at most :data:`NAMESPACE_MAX_LENGTH` characters.
"""
from __future__ import annotations

import re

from dmf_sim.core.errors import ConfigError

__all__ = ['NAMESPACE_MAX_LENGTH', 'check_namespace']

NAMESPACE_MAX_LENGTH = 245
"""rmw's RMW_NAMESPACE_MAX_LENGTH: a topic name's limit (255 - 8 characters reserved for the DDS
prefixes, RMW_TOPIC_MAX_NAME_LENGTH) less 2 for the shortest topic under it (``/x``)."""

_TOKEN = re.compile(r'[A-Za-z_][A-Za-z0-9_]*')
_ALLOWED = re.compile(r'[A-Za-z0-9_/]*')
_RULE = ("tokens of letters, digits and '_' not starting with a digit, separated by single '/', "
         'e.g. /truck1')


def check_namespace(value, option: str = '--namespace') -> str:
    """``value`` as an absolute ROS 2 namespace (``/truck1``; ``''`` for none or the root
    ``/``), else a one-line :class:`ConfigError` naming ``option``, the rule broken and where."""
    if value is None:
        return ''
    if not isinstance(value, str):
        raise ConfigError(f'{option} {value!r}: a namespace must be text ({_RULE})')
    if value in ('', '/'):
        return ''
    ns = value if value.startswith('/') else '/' + value

    def refuse(why: str) -> ConfigError:
        return ConfigError(f'{option} {value!r}: not a valid ROS 2 namespace, {why} ({_RULE})')

    bad = next((i for i, ch in enumerate(ns) if not _ALLOWED.fullmatch(ch)), None)
    if bad is not None:
        raise refuse(f'character {ns[bad]!r} is not allowed')
    if '//' in ns:
        raise refuse("it contains '//'")
    if ns.endswith('/'):
        raise refuse("it ends with '/'")
    for token in ns[1:].split('/'):
        if not _TOKEN.fullmatch(token):
            raise refuse(f'token {token!r} starts with a digit')
    if len(ns) > NAMESPACE_MAX_LENGTH:
        raise refuse(f'{len(ns)} characters, at most {NAMESPACE_MAX_LENGTH}')
    return ns
