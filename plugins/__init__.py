"""Built-in wholehand plug-ins, one module each, registered through entry points."""
