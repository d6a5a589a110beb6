"""Contact estimation: the hand as a geometric contact sensor."""

from wholehand.contacts.base import ContactEstimator, ContactSet

__all__ = ["ContactEstimator", "ContactSet"]
