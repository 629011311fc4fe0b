from tests.tasks.fakes import _one_torch_thread, fake_data  # noqa: F401  (shared fixtures)
