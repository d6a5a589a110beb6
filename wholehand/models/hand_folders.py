"""Where hand folders are: the shipped hands (`robots/`), a user's hand.toml by name or path."""

from __future__ import annotations

from pathlib import Path

from wholehand.errors import ConfigError


def shipped_hands_dir() -> Path:
    """The folder of hands shipped with wholehand (``robots/``)."""
    import wholehand_robots

    return Path(wholehand_robots.__file__).parent


def is_shipped_hand(folder: Path) -> bool:
    """Whether the hand folder ``folder`` is one of the shipped hands (``robots/<name>/``)."""
    return folder.resolve().parent == shipped_hands_dir().resolve()


def available_hands() -> list[str]:
    """Names of the shipped hands."""
    return sorted(p.parent.name for p in shipped_hands_dir().glob("*/hand.toml"))


def resolve_hand_config(name_or_path: str | Path) -> Path:
    """Path of a hand.toml from a shipped hand name, a hand folder or a hand.toml path."""
    candidate = Path(name_or_path)
    if candidate.exists():
        return candidate / "hand.toml" if candidate.is_dir() else candidate
    shipped = shipped_hands_dir() / str(name_or_path) / "hand.toml"
    if shipped.is_file():
        return shipped
    raise ConfigError(
        f"no hand named {str(name_or_path)!r}: shipped hands are {available_hands()}; "
        "or pass the path of a folder holding hand.toml"
    )
