"""Service settings in one place (pydantic settings; environment variables prefixed ``ISORIG_``)."""

from __future__ import annotations

from pathlib import Path

import platformdirs
from pydantic import Field, SecretStr
from pydantic_settings import BaseSettings, SettingsConfigDict

REPO_STATIC_DIR = Path(__file__).resolve().parent.parent / "frontend" / "static"


class Settings(BaseSettings):
    """Everything the service can be told; every field can be set as ``ISORIG_<NAME>``."""

    model_config = SettingsConfigDict(env_prefix="ISORIG_", extra="ignore")

    data_dir: Path = Field(default_factory=lambda: Path(platformdirs.user_data_dir("isorig")),
                           description="where the SQLite database and the operator token file live")
    database_url: str | None = Field(default=None, description="any SQLAlchemy URL; default SQLite in data_dir")
    operator_token: SecretStr | None = Field(default=None, description="bearer token for actions that move the "
                                             "rig or change records; generated and saved in data_dir if unset")
    host: str = "127.0.0.1"
    port: int = 8000
    static_dir: Path = REPO_STATIC_DIR
    max_test_duration_s: float = Field(default=4 * 3600.0, description="longest test the API accepts")
    max_speed: float = Field(default=100.0, description="largest speed factor of a simulated test")
    stream_history_s: float = Field(default=10.0, description="simulated seconds of samples a late client gets")
    worker_start_method: str = Field(default="forkserver", description="multiprocessing start method: forkserver "
                                     "or spawn (never fork from the threaded server)")
    worker_realtime: bool = Field(default=True, description="ask for real-time scheduling of the rig worker "
                                  "(SCHED_RR if permitted, else nice -10, else normal)")
    service_nice: int = Field(default=0, description="nice increment `isorig serve` applies to itself at start "
                              "(e.g. -10 on a shared machine: steadier streaming; needs root or CAP_SYS_NICE)")
    ws_per_message_deflate: bool = Field(default=False, description="compress websocket messages (saves "
                                         "bandwidth on slow links, costs server CPU per client)")
    viewer: bool = Field(default=True, description="serve the 3D view under /viewer/ (backend.viewer)")
    commit_interval_s: float = Field(default=0.5, description="samples are committed at least this often (wall)")

    @property
    def resolved_database_url(self) -> str:
        if self.database_url:
            return self.database_url
        return f"sqlite:///{self.data_dir / 'isorig.db'}"

    @property
    def token_file(self) -> Path:
        return self.data_dir / "operator-token"
