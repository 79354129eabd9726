// Charts of the dashboard: Vega-Lite specs built by the service (GET /api/v1/charts/...,
// jobs/views/charts.py) rendered by vega-embed, which the service serves itself
// (/vendor/vega.js). The page's Content-Security-Policy forbids eval, so expressions run in
// Vega's interpreter (ast: true); vega-embed's and the tooltip's own styles are in style.css.

const OPTIONS = {
  mode: "vega-lite", renderer: "svg", actions: false, ast: true, defaultStyle: false,
  tooltip: { disableDefaultStyle: true, theme: "light" },
};

// Draw `spec` into a new figure appended to `container`; resolves to the Vega view.
export async function chart(container, spec) {
  const figure = document.createElement("div");
  figure.className = "chart";
  container.appendChild(figure);
  const result = await window.vegaEmbed(figure, spec, OPTIONS);
  return result.view;
}

// A muted line in `container` (why there is no chart).
export function note(container, text) {
  const p = document.createElement("p");
  p.className = "muted";
  p.textContent = text;
  container.appendChild(p);
}
