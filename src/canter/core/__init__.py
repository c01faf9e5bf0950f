"""Pure numerical pieces shared by the algorithms: networks, normalizers, GAE, the replay buffer, seeding and the
JAX runtime setup."""
