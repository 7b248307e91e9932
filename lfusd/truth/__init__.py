"""Ground truth from raw passes: motion keys, their derivation over a dataset, verification."""
