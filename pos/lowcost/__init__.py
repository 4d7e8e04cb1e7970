"""The low-cost payload (seeds 000, 001): time synchronisation, exposure times, 15-state UKF, optic-flow attitude."""
