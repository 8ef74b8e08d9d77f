"""The router's access control, generated from :data:`fleet.bus.keys.ACCESS`.

Zenoh (1.x) checks every message twice at the router: on *ingress* from the sender's
session and on *egress* to each receiver's session. So each :class:`~fleet.bus.keys.KeyUse`
becomes these rules for its identity (one Zenoh subject per identity, named by its user):

========== ====================================================== =========================
use        ingress (the identity sends)                           egress (it receives)
========== ====================================================== =========================
put        ``put``, ``delete``                                    –
subscribe  ``declare_subscriber``                                 ``put``, ``delete``
token      ``liveliness_token``                                   –
watch      ``declare_liveliness_subscriber``, ``liveliness_query`` ``liveliness_token``, ``reply``
serve      ``declare_queryable``, ``reply``                       ``query``
query      ``query``                                              ``reply``
========== ====================================================== =========================

A publisher also needs to see the subscribers it publishes to (a declared Zenoh publisher
sends nothing while it knows of no matching subscriber), so ``put`` on a key also allows, on
egress, ``declare_subscriber`` for every key expression some identity subscribes to that
intersects it (``fleet/*/status`` for ``fleet/robot1/status``), and ``query`` likewise
``declare_queryable`` for the queryables it may ask. That tells an identity only that someone
listens where it may already publish; no data.

Everything else is denied (``default_permission: deny``). The router's own session (the
process that hosts it: ``fleet run``, ``fleet sim``) is not subject to these rules.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Iterable
from typing import Any

import zenoh

from fleet.bus.keys import KeyUse, Role, Use, access_of

Flow = tuple[str, ...]

#: (ingress messages, egress messages) of each use.
MESSAGES: dict[Use, tuple[Flow, Flow]] = {
    "put": (("put", "delete"), ()),
    "subscribe": (("declare_subscriber",), ("put", "delete")),
    "token": (("liveliness_token",), ()),
    "watch": (("declare_liveliness_subscriber", "liveliness_query"), ("liveliness_token", "reply")),
    "serve": (("declare_queryable", "reply"), ("query",)),
    "query": (("query",), ("reply",)),
}


#: The declarations a use needs to see (on egress), and of which use of the others.
_SEES: dict[Use, tuple[str, Use]] = {
    "put": ("declare_subscriber", "subscribe"),
    "query": ("declare_queryable", "serve"),
}


def _wild(key: str) -> bool:
    return "*" in key or "$" in key


class _Declared:
    """The key expressions of one use (``subscribe`` or ``serve``) over all identities,
    indexed so that a fleet of thousands of robots is matched quickly."""

    def __init__(self, keys: Iterable[str]) -> None:
        ks = set(keys)
        self.concrete = {k for k in ks if not _wild(k)}
        self.wild = sorted(k for k in ks if _wild(k))

    def intersecting(self, key: str) -> list[str]:
        """The expressions an ACL rule needs to cover every declared expression that
        intersects ``key``: the wild ones that do, and ``key`` itself for the concrete ones
        (a concrete key intersecting ``key`` is included in it)."""
        ke = zenoh.KeyExpr(key)
        out = [w for w in self.wild if ke.intersects(zenoh.KeyExpr(w))]
        if _wild(key) or key in self.concrete:
            out.append(key)
        return out


def identity_rules(
    user: str, uses: Iterable[KeyUse], declared: dict[Use, _Declared] | None = None
) -> list[dict[str, Any]]:
    """Zenoh ACL rules allowing ``user`` exactly ``uses``: one rule per (flow, message),
    with the key expressions that need it. ``declared``: the subscribers and queryables of
    every identity (what a ``put`` or ``query`` needs to see, see the module docstring)."""
    keys: dict[tuple[str, str], list[str]] = defaultdict(list)
    seen: set[tuple[str, str, str]] = set()

    def allow(flow: str, msg: str, key: str) -> None:
        if (flow, msg, key) not in seen:
            seen.add((flow, msg, key))
            keys[(flow, msg)].append(key)

    for u in uses:
        ingress, egress = MESSAGES[u.use]
        for flow, msgs in (("ingress", ingress), ("egress", egress)):
            for m in msgs:
                allow(flow, m, u.key)
        if u.use in _SEES and declared is not None:
            msg, their_use = _SEES[u.use]
            for k in declared[their_use].intersecting(u.key):
                allow("egress", msg, k)
    return [
        {
            "id": f"{user}.{flow}.{msg}",
            "messages": [msg],
            "flows": [flow],
            "permission": "allow",
            "key_exprs": exprs,
        }
        for (flow, msg), exprs in sorted(keys.items())
    ]


def access_control(
    identities: dict[str, tuple[Role, str | None]], *, certificates: bool = False
) -> dict[str, Any]:
    """The ``access_control`` section of the router's config for ``identities`` (user name ->
    (role, robot name or ``None``)): default deny, each user allowed exactly its role's uses.
    ``certificates``: a session must also present the TLS client certificate whose common
    name is the identity (mutual TLS)."""
    rules: list[dict[str, Any]] = []
    subjects: list[dict[str, Any]] = []
    policies: list[dict[str, Any]] = []
    uses = {user: access_of(role, robot) for user, (role, robot) in identities.items()}
    declared: dict[Use, _Declared] = {
        use: _Declared(u.key for mine in uses.values() for u in mine if u.use == use)
        for use in ("subscribe", "serve")
    }
    for user in identities:
        mine = identity_rules(user, uses[user], declared)
        rules += mine
        subject: dict[str, Any] = {"id": user, "usernames": [user]}
        if certificates:
            subject["cert_common_names"] = [user]
        subjects.append(subject)
        policies.append({"rules": [r["id"] for r in mine], "subjects": [user]})
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": rules,
        "subjects": subjects,
        "policies": policies,
    }


#: How :func:`describe` names what a rule allows: (flow, message) -> verb.
VERBS: dict[tuple[str, str], str] = {
    ("ingress", "put"): "publishes",
    ("egress", "put"): "receives",
    ("ingress", "liveliness_token"): "holds",
    ("ingress", "declare_liveliness_subscriber"): "watches",
    ("ingress", "declare_queryable"): "serves",
    ("ingress", "query"): "asks",
}


def describe(acl: dict[str, Any]) -> dict[str, dict[str, list[str]]]:
    """What each subject of a router's ``access_control`` section may do, read back from its
    rules: ``{subject: {verb: [key expressions]}}`` with the verbs of :data:`VERBS`."""
    rules = {r["id"]: r for r in acl.get("rules", [])}
    out: dict[str, dict[str, list[str]]] = {}
    for policy in acl.get("policies", []):
        for subject in policy.get("subjects", []):
            mine = out.setdefault(subject, {})
            for rid in policy.get("rules", []):
                r = rules.get(rid, {})
                if r.get("permission") != "allow":
                    continue
                for flow in r.get("flows", []):
                    for msg in r.get("messages", []):
                        verb = VERBS.get((flow, msg))
                        if verb is not None:
                            mine.setdefault(verb, []).extend(r.get("key_exprs", []))
    return out
