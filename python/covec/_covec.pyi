# The extension module (python/src/lib.rs); the public API is the package's (covec/__init__.py).
from typing import Any, Optional, Sequence, Tuple, Union

# (name, data): data a file's bytes, or (samples, height, width, channels, "u8"|"u16"|"f32").
_Given = Tuple[str, Union[bytes, Tuple[bytes, int, int, int, str]]]

VERSION: str

def defaults() -> str: ...
def vectorize(
    image: _Given,
    *,
    albedo: Optional[_Given],
    masks: Optional[Sequence[_Given]],
    labels: Optional[_Given],
    paths: int,
    mode: str,
    seed: int,
    max_size: int,
    threads: Optional[int],
    progress: Optional[Any],
    max_pixels: int,
    max_masks: int,
    accept_truncated: bool,
) -> Tuple["Scene", str, str]: ...

class Scene:
    @staticmethod
    def from_json(json: bytes, max_pixels: int) -> "Scene": ...
    def json(self) -> str: ...
    def size(self) -> Tuple[int, int, int, int]: ...
    def svg(self, flatten: bool, precision: Optional[int]) -> str: ...
    def layers(self, precision: Optional[int]) -> list[Tuple[str, str]]: ...
    def pdf(self) -> bytes: ...
    def png(self, width: Optional[int], max_pixels: int) -> bytes: ...
    def pixels(self, width: Optional[int], max_pixels: int) -> Tuple[bytes, int, int]: ...
    def paths(
        self,
    ) -> list[Tuple[str, str, str, float, str, list[Tuple[float, float]]]]: ...
    def changed(self) -> list[Tuple[str, str, str, float, float]]: ...
    def recolor(self, changes: Sequence[Tuple[Any, Any]]) -> "Scene": ...
    def recolor_by_reference(
        self,
        reference: _Given,
        original: Optional[_Given],
        k: int,
        tau: float,
        gamma: float,
        delta: float,
        epsilon: float,
        max_pixels: int,
    ) -> "Scene": ...
