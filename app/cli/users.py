"""Users and API tokens from the command line."""

from __future__ import annotations

import sys

import click

from app.cli.base import friendly_errors, load_settings, main, open_sessions
from app.core.models import Role


@main.group()
def user() -> None:
    """Manage users."""


@user.command("add")
@click.argument("name")
@click.option("--role", type=click.Choice([r.value for r in Role]), required=True)
@click.option("--password-stdin", is_flag=True, help="Read the password from standard input.")
@friendly_errors
def user_add(name: str, role: str, password_stdin: bool) -> None:
    """Add a user; the password comes from a prompt or --password-stdin."""
    from app.users.service import create_user

    if password_stdin:
        password = sys.stdin.readline().rstrip("\r\n")
    else:
        password = click.prompt("Password", hide_input=True, confirmation_prompt=True)
    with open_sessions(load_settings())() as session:
        created = create_user(session, name, password, Role(role))
    click.echo(f"added user {created.username} ({created.role.value})", err=True)


@user.command("list")
@friendly_errors
def user_list() -> None:
    """List users."""
    from app.users.service import list_users

    with open_sessions(load_settings())() as session:
        for row in list_users(session):
            state = "" if row.is_active else "  (inactive)"
            click.echo(f"{row.id}\t{row.username}\t{row.role.value}{state}")


@main.command()
@click.argument("name")
@click.option("--label", default="cli", show_default=True, help="A name for the token.")
@friendly_errors
def token(name: str, label: str) -> None:
    """Print a new API token for user NAME (stdout: the token alone)."""
    from app.users.service import create_token, user_by_name

    with open_sessions(load_settings())() as session:
        _, text = create_token(session, user_by_name(session, name), label)
    click.echo(text)


@main.group()
def tokens() -> None:
    """List and revoke API tokens."""


@tokens.command("list")
@click.argument("name")
@friendly_errors
def tokens_list(name: str) -> None:
    """List user NAME's tokens."""
    from app.users.service import list_tokens, user_by_name

    with open_sessions(load_settings())() as session:
        for row in list_tokens(session, user_by_name(session, name)):
            state = f"revoked {row.revoked_at:%Y-%m-%d %H:%M}" if row.revoked_at else "active"
            click.echo(f"{row.id}\t{row.prefix}…\t{row.name}\t{state}")


@tokens.command("revoke")
@click.argument("token_id", type=int)
@friendly_errors
def tokens_revoke(token_id: int) -> None:
    """Revoke token TOKEN_ID."""
    from app.users.service import revoke_token

    with open_sessions(load_settings())() as session:
        revoke_token(session, token_id, actor=None)
    click.echo(f"revoked token {token_id}", err=True)
