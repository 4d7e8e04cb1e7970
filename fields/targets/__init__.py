"""Target fields: the rotating coded-target plate, its printable sheet."""
