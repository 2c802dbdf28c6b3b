"""Who sent an override, as the farm's Zenoh access control vouches for it.

Measured on eclipse-zenoh 1.10.2 from Python (tests/controller/test_roles.py): a queryable cannot
learn the authenticated user of a query. ``Query.source_info`` is None unless the querier chose
to set it (so it proves nothing), the router's admin space (``@/<zid>/session/transport/unicast/*``,
``@/<zid>/router``) and ``SessionInfo.links()`` give the client's zid and addresses but no user
name (``auth_identifier`` is null for user/password logins), and ACL key templates bound to the
user (``${username}``) exist only as an unmerged proposal (eclipse-zenoh/zenoh#2662).

So identity is bound by key: besides the contract key ``farm/{site}/override/{command}``, every
user may query ``farm/{site}/override/{command}/by/{user}`` for the commands their role allows,
and no user may query another's. The rules for those keys are derived here, at start-up, from
the ACL the deployment config already holds: for each policy, each user name of its subjects and
each of its rules that touches an override key ``K``, the same rule on ``K/by/{user}`` for that
user alone. A query arriving on ``.../by/{user}`` through a router enforcing this ACL was sent by
``user``; the controller is that router, so the bus hands ``user`` to the handler. The contract
keys keep working for every role allowed them, with no authenticated name (``user`` None).
"""
from __future__ import annotations

import re

import zenoh

from controller.errors import BadInput

BY = "by"
USER = re.compile(r"^[A-Za-z0-9_.-]{1,64}$")   # a plain key chunk, and no ':' (the dictionary's separator)
_OVERRIDE = re.compile(r"^farm/[^/]+/override/")


def overrides_key(key: str) -> bool:
    return bool(_OVERRIDE.match(key))


def _asks(rule: dict) -> bool:
    """Whether a rule may let a client query (ingress is the querier's side of the router)."""
    return "query" in rule.get("messages", []) and "ingress" in rule.get("flows", ["ingress", "egress"])


def _impersonates(key: str) -> bool:
    """A rule key that includes some user's ``.../by/{user}`` keys: whoever it lets query them could
    pose as that user. Those keys are derived here, never written by hand."""
    try:
        return zenoh.KeyExpr(key).intersects(zenoh.KeyExpr(f"farm/*/override/*/{BY}/*"))
    except zenoh.ZError:
        return False   # not a key expression: zenoh itself refuses the config


def bind_identities(acl: dict, where: str = "access_control") -> dict:
    """``acl`` (a zenoh ``access_control`` section) with every user's own override keys added.
    BadInput if a user name is not a plain key chunk, or an allowing query rule on override keys
    uses ``**`` (it would let its users query every other user's keys: pose as anybody)."""
    if not acl.get("enabled"):
        return acl
    rules = {r.get("id"): r for r in acl.get("rules", [])}
    for rule in rules.values():
        if rule.get("permission") == "allow" and _asks(rule):
            for key in rule.get("key_exprs", []):
                if _impersonates(key):
                    raise BadInput(where, f"rules.{rule.get('id')}",
                                   f"{key!r} would let its users pose as another user: name the commands "
                                   "or use farm/*/override/* (one chunk)")
    subjects = {s.get("id"): s for s in acl.get("subjects", [])}
    extra_rules, extra_subjects, extra_policies = [], [], []
    for p_index, policy in enumerate(acl.get("policies", [])):
        overriding = [rules[r] for r in policy.get("rules", []) if r in rules
                      and any(overrides_key(k) for k in rules[r].get("key_exprs", []))]
        if not overriding:
            continue
        for s_id in policy.get("subjects", []):
            subject = subjects.get(s_id, {})
            for user in subject.get("usernames", []):
                if not USER.match(user):
                    raise BadInput(where, f"subjects.{s_id}", f"user name {user!r}: letters, digits, _ . - only")
                tag = f"{policy.get('id', p_index)} as {user} ({s_id})"
                ids = []
                for rule in overriding:
                    ids.append(f"{rule['id']} as {user} ({s_id})")
                    keys = [f"{k}/{BY}/{user}" for k in rule["key_exprs"] if overrides_key(k)]
                    extra_rules.append({**rule, "id": ids[-1], "key_exprs": keys})
                extra_subjects.append({**subject, "id": tag, "usernames": [user]})
                extra_policies.append({"id": tag, "rules": ids, "subjects": [tag]})
    return {**acl, "rules": [*rules.values(), *_unique(extra_rules)],
            "subjects": [*subjects.values(), *_unique(extra_subjects)],
            "policies": [*acl.get("policies", []), *_unique(extra_policies)]}


def _unique(entries: list[dict]) -> list[dict]:
    seen: dict[str, dict] = {}
    for entry in entries:
        seen.setdefault(entry["id"], entry)
    return list(seen.values())


def identities_bound(acl: dict) -> bool:
    """Whether a session enforcing ``acl`` (as bind_identities left it) vouches for the user of a
    ``.../by/{user}`` key: only under default deny, where nobody else is let through to it."""
    return acl.get("enabled") is True and acl.get("default_permission") == "deny"


def user_of(suffix: str) -> tuple[str, str | None]:
    """``override/feed/by/ana`` -> ("override/feed", "ana"); a contract key -> (suffix, None)."""
    chunks = suffix.split("/")
    if len(chunks) == 4 and chunks[2] == BY:
        return "/".join(chunks[:2]), chunks[3]
    return suffix, None
