"""Target fields, control fields, file formats, CRS and reference frames (the base layer of dgcal)."""
