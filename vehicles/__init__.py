"""The AGV simulator: vehicles that drive the plant graph and talk to the runtime only over a bus."""
