"""System calibration: lever arm, boresight and exposure delay from EOPs and the POS (two-step, joint, integrated)."""
