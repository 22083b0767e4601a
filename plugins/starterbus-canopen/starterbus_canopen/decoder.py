"""Placeholder."""

from __future__ import annotations

from starterbus.core import Annotation, Profile


def annotate_frames(frames: list[str], profile: Profile | None) -> list[Annotation]:
    return []
