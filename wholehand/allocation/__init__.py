"""Force allocation over the current contact set."""

from wholehand.allocation.base import Allocation, AllocationStatus, Allocator

__all__ = ["Allocation", "AllocationStatus", "Allocator"]
