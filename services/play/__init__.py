"""Human-AI play in the browser (`cec play`): a study flow (consent, instructions, practice, rounds with
partners in random order, a Likert survey after each round, a completion code), the game served from the
jitted env and the agents' networks with their LSTM state carried, and durable records of every step and
answer that export to the evaluator's result table. See docs/play.md."""
