"""Browser end-to-end tests of the dashboard (Playwright + Debian chromium)."""
