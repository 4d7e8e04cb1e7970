"""Readers and writers of dgcal's own files and of other software's ground-control files."""
