"""What the flows run on: settings, the shared services, the exact-set scheduler and its worker
processes, agent stores (memory, Redis), metrics, logs and the event loop's priorities."""
