"""Hand descriptions shipped with wholehand: one folder per hand, each with a hand.toml."""
