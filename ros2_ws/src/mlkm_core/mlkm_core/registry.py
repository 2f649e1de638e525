"""A table of named parts (associators, motion models, cues): each name registered once, a
lookup that names the choices when it fails."""

from __future__ import annotations


class Registry[T]:
    """Parts by name, in the order registered."""

    def __init__(self, what: str) -> None:
        self.what = what  # what a part is, for messages ('method', 'motion model', 'cue')
        self.items: dict[str, T] = {}

    def add(self, name: str, item: T) -> T:
        if name in self.items:
            raise ValueError(f'{self.what} {name!r} registered twice')
        self.items[name] = item
        return item

    def remove(self, name: str) -> None:
        self.items.pop(name, None)

    def get(self, name: str) -> T:
        if name not in self.items:
            raise ValueError(
                f'unknown {self.what} {name!r}; choose one of {", ".join(sorted(self.items))}'
            )
        return self.items[name]

    def names(self) -> list[str]:
        return list(self.items)

    def values(self) -> list[T]:
        return list(self.items.values())
