"""
RL Zoo's value syntax inside a config block, read without running code: ``policy_kwargs`` strings such as
``"dict(net_arch=[64, 64], activation_fn=nn.ReLU)"`` through a small AST evaluator (never ``eval``), and
``lin_<initial value>`` learning-rate schedules; and :class:`ConfigError`, the error every config reader raises.
"""

from __future__ import annotations

import ast
import math
from typing import Any

from stable_baselines3.common.utils import LinearSchedule
from torch import nn

from sb3_hddpg.algorithms import ACTIVATIONS as ALL_ACTIVATIONS
from sb3_hddpg.algorithms import CONFIG_ACTIVATIONS
from sb3_hddpg.artifacts.values import brief

#: Activation functions a ``policy_kwargs`` string may name (the registry's, the subset both backends compute).
ACTIVATIONS: dict[str, type[nn.Module]] = {name: ALL_ACTIVATIONS[name] for name in CONFIG_ACTIVATIONS}


class ConfigError(ValueError):
    """A config file or block that cannot be used; the message names the file and the offending value."""


def parse_schedule(text: str, name: str, source: str = "config") -> LinearSchedule:
    """
    An RL Zoo schedule string, ``lin_<initial value>``: the value falls linearly from its initial value to 0
    at the end of training (SB3's :class:`LinearSchedule`, which saves as a value, not code).

    :param text: e.g. ``"lin_1e-3"``.
    :param name: the key, for messages.
    :param source: a name for messages.
    """
    kind, _, initial = text.partition("_")
    try:
        value = float(initial)
    except ValueError:
        value = math.nan
    if kind != "lin" or not (math.isfinite(value) and 0 < value <= 1):
        raise ConfigError(
            f"Expected {name} in {source} to be a number or a schedule 'lin_<initial value in (0, 1]>' "
            f"(RL Zoo's linear schedule), actually: {brief(text)}"
        )
    return LinearSchedule(value, 0.0, 1.0)


def parse_policy_kwargs(text: str, source: str = "config") -> dict[str, Any]:
    """
    Evaluate an RL Zoo ``policy_kwargs`` string safely: literals, lists, dicts, ``dict(...)`` calls and the
    activation names of :data:`ACTIVATIONS` (as ``nn.X``, ``th.nn.X`` or ``torch.nn.X``); nothing else.
    """
    try:
        tree = ast.parse(text.strip(), mode="eval")
    except SyntaxError:
        raise ConfigError(f"Cannot parse policy_kwargs in {source}: {brief(text)}") from None
    value = _safe_value(tree.body, text, source)
    if not isinstance(value, dict):
        raise ConfigError(f"Expected policy_kwargs in {source} to be a dict, actually: {brief(text)}")
    return value


def _safe_value(node: ast.AST, text: str, source: str) -> Any:
    if isinstance(node, ast.Constant):
        return node.value
    if isinstance(node, ast.List):
        return [_safe_value(e, text, source) for e in node.elts]
    if isinstance(node, ast.Tuple):
        return tuple(_safe_value(e, text, source) for e in node.elts)
    if isinstance(node, ast.Dict):
        pairs = [(k, v) for k, v in zip(node.keys, node.values) if k is not None]
        if len(pairs) == len(node.keys):  # no ``**spread``
            return {_safe_value(k, text, source): _safe_value(v, text, source) for k, v in pairs}
    if isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.USub):
        return -_safe_value(node.operand, text, source)
    if (
        isinstance(node, ast.Call)
        and isinstance(node.func, ast.Name)
        and node.func.id == "dict"
        and not node.args
    ):
        return {kw.arg: _safe_value(kw.value, text, source) for kw in node.keywords if kw.arg is not None}
    if isinstance(node, ast.Attribute):
        dotted = ast.unparse(node)
        name = dotted.rsplit(".", 1)[-1]
        if dotted in (f"nn.{name}", f"th.nn.{name}", f"torch.nn.{name}") and name in ACTIVATIONS:
            return ACTIVATIONS[name]
    raise ConfigError(
        f"Unsupported expression {brief(ast.unparse(node))} in policy_kwargs of {source}: {brief(text)}"
    )
