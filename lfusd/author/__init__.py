"""Stage authoring with pxr: stages, vocabulary, labels, rigs, rules, people, scenes."""
