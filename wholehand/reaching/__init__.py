"""Reaching: bringing the hand to a grasp."""

from wholehand.reaching.base import Reacher

__all__ = ["Reacher"]
