"""Who may do what: one table of actions and the lowest role allowed for each, read by the
routes (their dependencies, ``app.core.security``), the services (``may``) and the browser
(each page's ``user-may`` meta and ``GET /users/me``'s ``may``), so no rank is written twice."""

from __future__ import annotations

import enum

from app.core.models import Role, User


class Action(enum.StrEnum):
    """What a user does that not every role may."""

    label = "label"
    """Save one's own labels, click, draw, import labels, start teacher runs."""
    review = "review"
    """Accept, reject, approve or send back others' labels, propagate, train and promote,
    delete frames, hand work out, see everyone's work and figures."""
    cancel_any_job = "cancel_any_job"
    """Cancel a job someone else started."""
    administer = "administer"
    """Manage users and the instance's settings (the embedding cache, the label configuration)."""


PERMISSIONS: dict[Action, Role] = {
    Action.label: Role.annotator,
    Action.review: Role.reviewer,
    Action.cancel_any_job: Role.reviewer,
    Action.administer: Role.admin,
}
"""Each action and the lowest role that may do it (every higher role may too)."""


def may(user: User, action: Action) -> bool:
    """Whether ``user``'s role allows ``action``."""
    return user.role.rank >= PERMISSIONS[action].rank


def allowed(role: Role) -> list[str]:
    """The actions ``role`` may do, as the browser reads them."""
    return [action.value for action, lowest in PERMISSIONS.items() if role.rank >= lowest.rank]
