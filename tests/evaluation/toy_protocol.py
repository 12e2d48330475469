"""A protocol that lives outside the package: what a new protocol needs (this module and toy_protocols/toy.yaml)."""

from dataclasses import dataclass
from typing import ClassVar

from ushape.evaluation.plugin import Output, Protocol
from ushape.evaluation.tables import Table


@dataclass
class Toy(Protocol):
    """Per encoder: how many single-view records the context holds, and its own setting times that."""

    name: ClassVar[str] = "toy"
    weight: float = 1.0

    def run(self, context) -> Output:
        records = context.single_view(1.0)  # shared with the single-view protocol: scored once
        row = {"encoder": context.spec.name, "views": len(records), "weighted": self.weight * len(records)}
        return Output(rows={"toy": [row]})

    def tables(self, result) -> list:
        table = Table("Table T: toy", "single-view records per encoder", ["encoder", "views", "weighted"])
        table.rows = [[r["encoder"], r["views"], r["weighted"]] for r in result.get("toy", [])]
        return [table]

    def csvs(self, result) -> dict:
        return {"toy": result.get("toy", [])}
