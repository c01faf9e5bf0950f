"""Many runs at once: child-process jobs, the Optuna study storage, search spaces, `tune` and `bench`."""
