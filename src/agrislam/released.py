"""What stands for a part of a world model let go after its run (`WorldModel.release`)."""

from __future__ import annotations

from typing import Any, NoReturn


class Released:
    """A released part of a world model: any use of it says what happened."""

    def __init__(self, part: str) -> None:
        self._part = part

    def _refuse(self) -> NoReturn:
        raise RuntimeError(
            f"the world model's {self._part!r} was released once the run's map was taken "
            "(WorldModel.release): it maps and answers nothing more"
        )

    def __getattr__(self, name: str) -> Any:
        self._refuse()

    def __len__(self) -> int:
        self._refuse()

    def __getitem__(self, key: Any) -> Any:
        self._refuse()
