// Every table of a page sorts by a click on its header (Material for MkDocs' recipe with tablesort;
// document$ emits on each page load, instant navigation included).
document$.subscribe(() => {
  document.querySelectorAll("article table:not([class])").forEach((table) => new Tablesort(table));
});
